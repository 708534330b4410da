"""The selftest's second and third paths: model files as a user's, and the shared code.

Beside the engine-level faults (:mod:`validation.faults.catalogue`, injected into the
engine only), ``cip-validate selftest`` runs

* the file-level faults of :mod:`validation.faults.file` (edited copies of the
  shipped MJCF read as ``--mjcf`` reads them; flagged by ``model.conforms``
  naming the deviation) and checks that the equivalent rewrites pass;
* the shared-code faults of :mod:`validation.faults.shared` (flagged by the
  anchors of :mod:`validation.checks.anchors`).

Every row carries ``path`` ("file" or "shared"); ``--power`` bisects each
fault type of each path.
"""

from __future__ import annotations

from cipcore.models import MODEL_NAMES
from validation.checks.stats import FAIL
from validation.faults.file import FILE_FAULT_TYPES, equivalent_failures, file_power, file_rows
from validation.faults.shared import (
    SHARED_FAULT_TYPES,
    flagged_by_shared,
    shared_power,
    shared_rows,
)

#: Fault types of the file and shared-code paths (for ``--faults``).
PATH_FAULT_TYPES = (*FILE_FAULT_TYPES, *SHARED_FAULT_TYPES)


def clean_failures(seed: int, n_realizations: int) -> list[str]:
    """What fails on the unmodified files, code and the equivalent rewrites (should be none)."""
    from validation.checks.conformance import conformance_checks

    bad = [c.name for c in conformance_checks(None, MODEL_NAMES) if c.status == FAIL]
    bad += flagged_by_shared(None, seed)
    for name, failed in equivalent_failures(seed, n_realizations).items():
        bad += [f"{name}: {c}" for c in failed]
    return bad


def path_rows(seed: int, n_realizations: int, kinds: list[str] | None = None) -> list[dict]:
    """One row per catalogued file-level and shared-code fault."""
    return file_rows(seed, n_realizations, kinds) + shared_rows(seed, kinds)


def path_power(rows: list[dict], seed: int, n_realizations: int) -> list[dict]:
    """The power curve (smallest flagged size) of each fault type of ``rows``' paths."""
    out, seen = [], set()
    for r in rows:
        kind = r["fault"]
        if r.get("path") not in ("file", "shared") or kind in seen:
            continue
        seen.add(kind)
        if r["path"] == "file":
            out.append(file_power(kind, seed, n_realizations))
        else:
            out.append(shared_power(kind, seed))
    return out
