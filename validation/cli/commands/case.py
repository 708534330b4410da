"""``cip-validate case``: the file protocol (:mod:`validation.exchange.case`).

``case export`` writes the case, ``case run`` runs it with a registered engine
in process (the reference trajectories), ``case check`` validates the
trajectories an engine wrote.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

from cipcore.atomic import atomic_path
from cipcore.params import ParameterError
from validation.cli.ci_options import add_ci_options
from validation.cli.domains import add_option
from validation.cli.exitcodes import EXIT_FAIL, EXIT_OK


def cmd_export(a: argparse.Namespace) -> int:
    from cip.mjcf_params import model_files
    from validation.cli.args import check_out_file
    from validation.exchange.case import export_case

    out = check_out_file("--out", a.out, (".npz",))
    case = export_case(out, a.seed, a.realizations, model_files(a.mjcf))
    names = ", ".join(s["name"] for s in case.scenarios)
    print(f"case written: {out} ({len(case.scenarios)} scenarios: {names}; seed {a.seed})")
    return EXIT_OK


def cmd_run(a: argparse.Namespace) -> int:
    from validation.cli.args import check_out_file
    from validation.exchange.case import load_case, run_case

    out = check_out_file("--out", a.out, (".npz",))
    traj = run_case(load_case(a.case), a.engine)
    with atomic_path(out) as tmp, open(tmp, "wb") as f:  # a file object: no ".npz" added
        np.savez(f, **traj)
    print(f"trajectories written: {out} (engine {a.engine})")
    return EXIT_OK


def _load_trajectories(path: str) -> dict[str, np.ndarray]:
    if not Path(path).is_file():
        raise ParameterError(f"--trajectories: no such file {path!r}")
    try:
        with np.load(path, allow_pickle=False) as z:
            return {k: z[k] for k in z.files}
    except (OSError, ValueError) as exc:
        raise ParameterError(f"--trajectories: cannot read {path!r} ({exc})") from None


def cmd_check(a: argparse.Namespace) -> int:
    from validation.cli.args import check_out_file
    from validation.cli.checklog import check_table, with_limit
    from validation.exchange.case import check_case, load_case

    junit = check_out_file("--junit", a.junit, (".xml",)) if a.junit else None
    case = load_case(a.case)
    t = time.perf_counter()
    traj = _load_trajectories(a.trajectories)
    checks = [with_limit(c.as_dict()) for c in check_case(case, traj, a.engine)]
    failed = any(c["status"] == "fail" for c in checks)
    if junit:
        from validation.cli.junit import run_cases, write_junit

        write_junit(run_cases({"checks": checks}, suite="case"), junit, time.perf_counter() - t)
    if a.json:
        from validation.cli.ci_options import run_environment
        from validation.report.document import jsonable

        print(json.dumps(jsonable({"cipval_case_check": 1, "pass": not failed, "checks": checks,
                                   **run_environment()})))  # fmt: skip
    elif not a.quiet or failed:
        print(check_table(checks))
    verdict = "FAIL" if failed else "pass"
    print(f"case check {verdict}: {sum(c['status'] == 'pass' for c in checks)} of {len(checks)} "
          f"checks pass ({a.trajectories} against {a.case})",
          file=sys.stderr if a.json else sys.stdout)  # fmt: skip
    return EXIT_FAIL if failed else EXIT_OK


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "case",
        help="file protocol for engines that run the controller themselves",
        description="Export a validation case (model, parameters, every noise draw), run it "
        "in process, or check the trajectories an engine wrote (README: Engines that run the "
        "controller themselves).",
    )
    cs = p.add_subparsers(dest="case_command", metavar="ACTION")
    cs.required = True
    e = cs.add_parser(
        "export", help="write case.npz",
        description="Write a case file: the model files, the scenarios (model, realisations, "
        "steps, dt, delay, gain, noise scale, amplitude, fields to record) and every "
        "standard-normal draw, for an engine that runs the controller itself.",
    )  # fmt: skip
    add_option(e, "--out", domain="npz out", default="case.npz", metavar="FILE.npz",
               help="case file to write")  # fmt: skip
    add_option(e, "--seed", domain="seed", default=1,
               help="root seed of the noise draws (integer >= 0)")  # fmt: skip
    add_option(e, "--realizations", domain="case realizations", default=4,
               help="realisations per scenario (count >= 2)")  # fmt: skip
    add_option(e, "--mjcf", domain="mjcf in", action="append", metavar="PATH",
                   help="a user's CIP model file instead of the shipped one")  # fmt: skip
    e.set_defaults(func=cmd_export)
    r = cs.add_parser(
        "run", help="run a case with a registered engine (reference trajectories)",
        description="Simulate every scenario of a case file with a registered rigid-body "
        "engine under the case's draws and write the trajectories an external engine "
        "should reproduce.",
    )  # fmt: skip
    add_option(r, "--case", domain="npz in", required=True, metavar="FILE.npz",
               help="case file written by `case export`")  # fmt: skip
    add_option(r, "--engine", domain="engine", default="mujoco",
               help="a registered rigid-body engine")  # fmt: skip
    add_option(r, "--out", domain="npz out", default="trajectories.npz", metavar="FILE.npz",
                   help="trajectories file to write")  # fmt: skip
    r.set_defaults(func=cmd_run)
    c = cs.add_parser(
        "check", help="validate the trajectories an engine wrote",
        description="Apply the run's direct checks (the exact linear twin under the case's "
        "draws, the rod's stretch, the delay measured from the response) to the "
        "trajectories an engine wrote: exit 0 when every check passes, 1 when one fails.",
    )  # fmt: skip
    add_option(c, "--case", domain="npz in", required=True, metavar="FILE.npz",
               help="case file written by `case export`")  # fmt: skip
    add_option(c, "--trajectories", domain="npz in", required=True, metavar="FILE.npz",
               help="the engine's trajectories (<scenario>/<field> arrays)")  # fmt: skip
    add_option(c, "--engine", domain="engine", default="mujoco",
                   help="the registered rigid-body engine whose discretisation the trajectories "
                   "follow: its measured twin and rod tolerances apply")  # fmt: skip
    c.add_argument("--json", action="store_true", help="one JSON object on stdout")
    add_ci_options(c, verbose=False)
    c.set_defaults(func=cmd_check)
