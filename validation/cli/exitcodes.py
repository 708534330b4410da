"""Exit statuses of ``cip-validate``: distinct, so that a CI gate can tell outcomes apart.

======  ==============================================================================
status  meaning
======  ==============================================================================
0       every check passed (and, with ``--baseline``, every number reproduced)
1       a validation check failed (the engine disagrees with the physics)
2       bad input: one line ``cip-validate: error: ...`` naming the parameter; no work
3       every check passed but a regression number moved beyond its tolerance
        (``run --baseline``); a failed check takes precedence (status 1)
4       the engine (or a stage) crashed: ``results.json`` is written, marked
        ``"partial": true``, naming the stage in ``"crashed"`` with the error
130     interrupted by SIGINT (finished stages kept; ``--resume`` finishes the run)
143     interrupted by SIGTERM (the same)
======  ==============================================================================
"""

from __future__ import annotations

EXIT_OK = 0
EXIT_FAIL = 1
EXIT_USAGE = 2
EXIT_REGRESSION = 3
EXIT_CRASH = 4
EXIT_SIGINT = 130
EXIT_SIGTERM = 143

#: status -> one-line meaning (printed by ``cip-validate exit-codes`` and the README)
MEANING = {
    EXIT_OK: "every check passed (and every regression number reproduced)",
    EXIT_FAIL: "a validation check failed",
    EXIT_USAGE: "bad input (one line naming the parameter); nothing computed",
    EXIT_REGRESSION: "checks passed but a regression number moved beyond its tolerance",
    EXIT_CRASH: "the engine or a stage crashed; results.json written, partial, naming the stage "
    "(engines: the engine's row crashed, every other row checked)",
    EXIT_SIGINT: "interrupted by SIGINT (finished stages kept)",
    EXIT_SIGTERM: "interrupted by SIGTERM (finished stages kept)",
}


def run_status(checks_failed: bool, regression_moved: bool) -> int:
    """The status of a finished run: a failed check (1) before a moved number (3)."""
    if checks_failed:
        return EXIT_FAIL
    return EXIT_REGRESSION if regression_moved else EXIT_OK
