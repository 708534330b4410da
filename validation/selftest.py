"""``cip-validate selftest``: inject every catalogued fault, show which check flags it.

For each fault of :data:`validation.faults.CATALOGUE` the suite's direct checks
(:func:`validation.agreement.instrument_checks`: the full model against its
exact linear twin, the rod's stretch, the delay measured from the engine's
response, the model's declared time step and integrator) run on the faulty
engine with the same seed as the unmodified one.  The selftest passes when the
unmodified model passes every check and every catalogued fault fails at least
one.  ``--power`` also bisects each fault type's size down to the smallest that
is still flagged (a power curve: below it the fault hides in the twin's floor).
"""

from __future__ import annotations

import argparse
import math
import time

from cipcore.models import MODEL_NAMES

from .agreement import instrument_checks
from .ci_options import add_ci_options, run_environment
from .cli_args import nonnegative_int, positive_int
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
    clean = flagged_by(None, seed, n_realizations)
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
    if a.junit:
        from .cli_args import check_out_file

        a.junit = check_out_file("--junit", a.junit, (".xml",))
    kinds = [k.strip() for k in a.faults.split(",")] if a.faults else None
    for k in kinds or []:
        if k not in FAULT_TYPES:
            raise ParameterError(f"--faults: unknown fault {k!r}; known: {', '.join(FAULT_TYPES)}")
    t = time.perf_counter()
    clean, rows = run_selftest(a.seed, a.realizations, kinds)
    power = []
    if a.power:
        power = [smallest_detectable(r["fault"], a.seed, a.realizations) for r in rows]
    ok = not clean and all(r["flagged"] for r in rows)
    if a.junit:
        from .junit import selftest_cases, write_junit

        write_junit(selftest_cases(clean, rows), a.junit, time.perf_counter() - t)
    if a.json:
        from .agreement import ROD_TOLERANCE, TWIN_METRIC_FLOOR, TWIN_TOLERANCE
        from .report import jsonable

        doc = {"cipval_selftest": 1, "pass": ok, "clean_failures": clean, "faults": rows,
               "power": power, "tolerances": {"twin_trajectory_relative_l2": TWIN_TOLERANCE,
               "twin_metric_floor": TWIN_METRIC_FLOOR, "rod_stretch_relative_l2": ROD_TOLERANCE},
               **run_environment()}  # fmt: skip
        print(json.dumps(jsonable(doc)))
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
    p = sub.add_parser(
        "selftest",
        help="inject each catalogued fault; show which check flags it",
        description="Run the suite's regression checks on the unmodified model and on the "
        "model with each catalogued fault injected (a wrong constant, delay, gain, noise "
        "scaling or integrator); the selftest passes when the unmodified model passes every "
        "check and every fault is flagged by at least one.",
    )
    p.add_argument("--seed", type=nonnegative_int, default=1,
                   help="root seed of every noise draw (integer >= 0)")  # fmt: skip
    p.add_argument("--realizations", type=positive_int, default=2,
                   help="noise realisations per run (count >= 1)")  # fmt: skip
    p.add_argument("--faults", metavar="A,B,...",
                   help="only these fault types (default: all: "
                   + ", ".join(FAULT_TYPES) + ")")  # fmt: skip
    p.add_argument("--power", action="store_true", help="bisect each type's smallest flagged size")
    p.add_argument("--json", action="store_true", help="print one JSON object on stdout")
    add_ci_options(p, verbose=False)
    p.set_defaults(func=cmd_selftest)
