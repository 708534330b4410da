"""``cip-validate engines``: every engine through the same checks, one table."""

from __future__ import annotations

import argparse
import json
import sys

from cipcore.registry import engine_names

from .cli_args import check_out_dir
from .engine_options import INTEGRATORS
from .profiles import PROFILES

EXIT_OK, EXIT_FAIL = 0, 1


def cmd_engines(a: argparse.Namespace) -> int:
    from cipcore.params import ParameterError

    from .engines import compare_engines, parse_engines, write_engine_reports

    names = parse_engines(a.engines)
    if a.threads is not None and a.threads < 1:
        raise ParameterError(f"threads must be an integer >= 1, got {a.threads}")
    if a.integrator is not None and a.integrator not in INTEGRATORS:
        raise ParameterError(
            f"--integrator must be one of {', '.join(INTEGRATORS)}, got {a.integrator!r}"
        )
    out = check_out_dir("--out", a.out)  # checked before any work
    say = (lambda n: None) if a.json else (lambda n: print(f"engine {n} ...", file=sys.stderr))
    results = compare_engines(names, a.profile, a.seed, a.threads, progress=say,
                              integrator=a.integrator)  # fmt: skip
    write_engine_reports(results, out, figures=not a.no_figures)
    if a.json:
        from .report import jsonable

        print(json.dumps(jsonable(results)))
    else:
        for r in results["engines"]:
            if r["status"] == "skipped":
                print(f"{r['engine']:12s} skipped: {r['reason']}")
                continue
            tp = r["throughput"]
            ratio = tp.get("ratio_to_mujoco")
            tw = r.get("twin_distance")
            dist = (f"twin distance single {tw['single']:.3g} coupled {tw['coupled']:.3g}"
                    if tw else "reference distance coupled "
                    f"{r['trajectory_distance']['coupled']:.3g}")  # fmt: skip
            print(
                f"{r['engine']:12s} {r['status']:12s} {dist}  "
                f"{tp['realization_steps_per_s']:.3g} steps/s"
                + (f" ({ratio:.3g} x MuJoCo CPU)" if ratio is not None else "")
            )
            if r["failed"]:
                print(f"{'':12s} failed: {', '.join(r['failed'])}")
        print(f"report: {out / 'report.md'}")
    return EXIT_OK if results["status"] != "fail" else EXIT_FAIL


def add_engines_command(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "engines",
        help="validate every registered engine through the same checks, one table",
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    registered = ", ".join(engine_names())
    p.add_argument("--engines", metavar="A,B,...",
                   help=f"engines to validate (default: all registered: {registered})")  # fmt: skip
    p.add_argument("--profile", choices=tuple(PROFILES), default="quick",
                   help="sizes of the checks (the profiles of `cip-validate run`)")  # fmt: skip
    p.add_argument("--seed", type=int, default=None,
                   help="root seed of every noise draw (default: the profile's)")  # fmt: skip
    p.add_argument("--integrator", default=None, metavar="NAME",
                   help=f"MuJoCo integrator for engines that follow the model file "
                   f"({', '.join(INTEGRATORS)}; default: the file's)")  # fmt: skip
    p.add_argument("--threads", type=int, default=None, help="worker threads (default: all cores)")
    p.add_argument("--out", default="cip-engines-out", help="output directory")
    p.add_argument("--no-figures", action="store_true", help="skip the speed-accuracy figure")
    p.add_argument("--json", action="store_true", help="one JSON object on stdout")
    p.set_defaults(func=cmd_engines)
