"""``cip-validate selftest``: inject every catalogued fault, show which check flags it.

For each fault of :data:`validation.faults.CATALOGUE` the suite's direct checks
(:func:`validation.agreement.instrument_checks`: the full model against its
exact linear twin, the rod's stretch, the delay measured from the engine's
response, the model's declared time step and integrator) run on the faulty
engine with the same seed as the unmodified one.  The selftest passes when the
unmodified model passes every check and every catalogued fault fails at least
one.  ``--power`` also bisects each fault type's size down to the smallest that
is still flagged (a power curve: below it the fault hides in the twin's floor).
The file-level and shared-code paths (:mod:`validation.selftest_paths`) add
their rows and power curves.
"""

from __future__ import annotations

import argparse
import math
import time

from cipcore.models import MODEL_NAMES

from .agreement import instrument_checks
from .faults import CATALOGUE, FAULT_TYPES, Fault, make_fault
from .stats import FAIL


def flagged_by(fault: Fault | None, seed: int, n_realizations: int) -> list[str]:
    """Names of the checks that fail with ``fault`` injected (all of them run)."""
    models = fault.models if fault is not None else MODEL_NAMES
    checks = instrument_checks(seed, n_realizations, threads=1, fault=fault, models=models)
    return [c.name for c in checks if c.status == FAIL]


def run_selftest(
    seed: int = 1, n_realizations: int = 2, kinds: list[str] | None = None
) -> tuple[list[str], list[dict]]:
    """(checks failing on the unmodified model, one row per catalogued fault)."""
    from .selftest_paths import clean_failures, path_rows

    clean = flagged_by(None, seed, n_realizations) + clean_failures(seed, n_realizations)
    rows = []
    for kind, size in CATALOGUE:
        if kinds and kind not in kinds:
            continue
        fault = make_fault(kind, size)
        t = time.perf_counter()
        failed = flagged_by(fault, seed, n_realizations)
        rows.append({
            "fault": kind, "size": size, "unit": fault.unit, "description": fault.description,
            "flagged": bool(failed), "by": failed, "seconds": round(time.perf_counter() - t, 2),
        })  # fmt: skip
    rows += path_rows(seed, n_realizations, kinds)  # model files as a user's, shared code
    return clean, rows


def smallest_detectable(kind: str, seed: int, n_realizations: int, iterations: int = 12) -> dict:
    """Bisection (geometric) on |size| between 1e-12 and the catalogue size.

    Fixed faults (flags, sign flips) and one-step delays have no smaller size:
    their row states that.  The sign of the catalogue size is kept.
    """
    spec = FAULT_TYPES[kind]
    size = dict(CATALOGUE)[kind]
    if spec.get("fixed") or spec.get("integer"):
        return {"fault": kind, "smallest_flagged": size, "note": "no smaller size exists"}
    identity = spec.get("identity", 0.0)  # the size that means "no fault"
    sign = math.copysign(1.0, size - identity)
    hi, lo = abs(size - identity), 1e-12
    if not flagged_by(make_fault(kind, identity + sign * hi), seed, n_realizations):
        return {"fault": kind, "smallest_flagged": None, "note": "catalogue size not flagged"}
    if flagged_by(make_fault(kind, identity + sign * lo), seed, n_realizations):
        unit = make_fault(kind, size).unit
        return {"fault": kind, "smallest_flagged": identity + sign * lo, "deviation": lo,
                "unit": unit, "note": "flagged down to the bisection's floor"}  # fmt: skip
    for _ in range(iterations):
        mid = math.sqrt(hi * lo)
        if flagged_by(make_fault(kind, identity + sign * mid), seed, n_realizations):
            hi = mid
        else:
            lo = mid
    return {
        "fault": kind,
        "smallest_flagged": identity + sign * hi,
        "largest_missed": identity + sign * lo,
        "deviation": hi,
        "missed_deviation": lo,
        "unit": make_fault(kind, size).unit,
    }


def format_table(clean: list[str], rows: list[dict]) -> str:
    out = ["unmodified model: " + ("pass" if not clean else "FAIL: " + ", ".join(clean)), ""]
    out.append(f"{'fault':<24} {'size':>10} {'unit':<9} {'flagged':<8} by")
    for r in rows:
        by = ", ".join(r["by"]) if r["by"] else "-"
        out.append(f"{r['fault']:<24} {r['size']:>10.4g} {r['unit']:<9} "
                   f"{'yes' if r['flagged'] else 'NO':<8} {by}")  # fmt: skip
    return "\n".join(out)


def cmd_selftest(a: argparse.Namespace) -> int:
    import json

    from cipcore.params import ParameterError, check_count

    check_count("realizations", a.realizations)
    kinds = [k.strip() for k in a.faults.split(",")] if a.faults else None
    from .selftest_paths import PATH_FAULT_TYPES, path_power

    known = (*FAULT_TYPES, *PATH_FAULT_TYPES)
    for k in kinds or []:
        if k not in known:
            raise ParameterError(f"--faults: unknown fault {k!r}; known: {', '.join(known)}")
    t = time.perf_counter()
    clean, rows = run_selftest(a.seed, a.realizations, kinds)
    power = []
    if a.power:
        power = [smallest_detectable(r["fault"], a.seed, a.realizations)
                 for r in rows if "path" not in r]  # fmt: skip
        power += path_power(rows, a.seed, a.realizations)
    ok = not clean and all(r["flagged"] for r in rows)
    if a.json:
        print(json.dumps({"pass": ok, "clean_failures": clean, "faults": rows, "power": power}))
    else:
        print(format_table(clean, rows))
        if power:
            print(
                "\nsmallest flagged deviation from the unmodified model per fault type "
                "(geometric bisection):"
            )
            for p in power:
                if p.get("deviation") is None:
                    print(f"  {p['fault']:<24} {p['smallest_flagged']!s:>10}  {p['note']}")
                    continue
                note = p.get("note") or f"(missed at deviation {p['missed_deviation']:.3g})"
                print(f"  {p['fault']:<24} {p['smallest_flagged']:>10.4g}  deviation "
                      f"{p['deviation']:.3g} {p['unit']} {note}")  # fmt: skip
        print(f"\nselftest {'passes' if ok else 'FAILS'}: {sum(r['flagged'] for r in rows)} of "
              f"{len(rows)} faults flagged, {time.perf_counter() - t:.1f} s (seed {a.seed}, "
              f"{a.realizations} realisations)")  # fmt: skip
    return 0 if ok else 1


def register_selftest(sub: argparse._SubParsersAction) -> None:
    """Add ``cip-validate selftest`` to the CLI's subcommands."""
    p = sub.add_parser("selftest", help="inject each catalogued fault; show which check flags it")
    p.add_argument("--seed", type=int, default=1)
    p.add_argument("--realizations", type=int, default=2)
    p.add_argument("--faults", metavar="A,B,...", help="only these fault types")
    p.add_argument("--power", action="store_true", help="bisect each type's smallest flagged size")
    p.add_argument("--json", action="store_true")
    p.set_defaults(func=cmd_selftest)
