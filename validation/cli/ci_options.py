"""Options a CI gate needs on ``run``, ``engines`` and ``selftest``: ``--junit``, ``--quiet``,
``--verbose``, and progress bars shown only on a terminal.

Progress bars redraw with carriage returns, which fill a CI log: they are shown
only when stderr is a terminal, never with ``--quiet``, and never when the
environment sets ``TQDM_DISABLE`` to a true value (``1``, ``true``, ``yes``),
tqdm's own switch.
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

__all__ = ["add_ci_options", "junit_file", "progress_enabled", "run_environment"]


def progress_enabled(quiet: bool = False) -> bool:
    """True when progress bars should be drawn (module docstring)."""
    if quiet or os.environ.get("TQDM_DISABLE", "").strip().lower() in ("1", "true", "yes"):
        return False
    return bool(getattr(sys.stderr, "isatty", lambda: False)())


def add_ci_options(p: argparse.ArgumentParser, verbose: bool = True) -> None:
    """Add ``--junit FILE``, ``--quiet`` (and ``--verbose``) to a command."""
    from validation.cli.domains import add_option

    add_option(
        p,
        "--junit",
        domain="xml out",
        metavar="FILE.xml",
        help="also write JUnit XML, one test case per check (for CI test reports)",
    )
    p.add_argument(
        "--quiet",
        action="store_true",
        help="no progress bars or stage lines; the table only when a check fails",
    )
    if verbose:
        p.add_argument(
            "--verbose",
            action="store_true",
            help="list every moved regression number, derived ones (intervals, "
            "standard errors, margins) included",
        )


def junit_file(a: argparse.Namespace) -> Path | None:
    """The ``--junit`` file, checked before any work (a writable .xml path), or None."""
    if not a.junit:
        return None
    from validation.cli.args import check_out_file

    return check_out_file("--junit", a.junit, (".xml",))


def run_environment(model_files: dict[str, str] | None = None) -> dict:
    """``versions``, ``platform`` and the numerics ``fingerprint`` (with the digests of
    ``model_files``, the ``--mjcf`` files, else of the shipped models) for a JSON output.

    Fixed for the life of a process but for the files' digests; reading the package
    metadata, CPU flags and BLAS kernels takes about 25 ms, so a run computes it once
    (its results file is rewritten after every stage)."""
    import platform

    from validation.regression.fingerprint import numerics_fingerprint
    from validation.regression.versions import package_versions

    return {"versions": package_versions(), "platform": platform.platform(),
            "fingerprint": numerics_fingerprint(model_files)}  # fmt: skip
