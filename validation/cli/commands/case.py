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
from validation.cli.args import (
    add_engine_arg,
    add_json_arg,
    add_mjcf_arg,
    add_seed_arg,
    check_out_file,
)
from validation.cli.ci_options import add_ci_options, junit_file
from validation.cli.domains import add_option
from validation.cli.exitcodes import EXIT_FAIL, EXIT_OK
from validation.cli.main import add_command, add_group, command


@command(
    "Write a case file: the model files, the scenarios (model, realisations, steps, dt, delay, "
    "gain, noise scale, amplitude, fields to record) and every standard-normal draw, for an "
    "engine that runs the controller itself.",
)
def cmd_export(a: argparse.Namespace) -> int:
    from cip.mjcf_params import model_files
    from validation.exchange.case import export_case

    out = check_out_file("--out", a.out, (".npz",))
    case = export_case(out, a.seed, a.realizations, model_files(a.mjcf))
    names = ", ".join(s["name"] for s in case.scenarios)
    print(f"case written: {out} ({len(case.scenarios)} scenarios: {names}; seed {a.seed})")
    return EXIT_OK


@command(
    "Simulate every scenario of a case file with a registered rigid-body engine under the case's "
    "draws and write the trajectories an external engine should reproduce.",
)
def cmd_run(a: argparse.Namespace) -> int:
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


@command(
    "Apply the run's direct checks (the exact linear twin under the case's draws, the rod's "
    "stretch, the delay measured from the response) to the trajectories an engine wrote: exit 0 "
    "when every check passes, 1 when one fails.",
)
def cmd_check(a: argparse.Namespace) -> int:
    from validation.cli.checklog import check_table, with_limit
    from validation.exchange.case import check_case, load_case

    junit = junit_file(a)
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


def _add_case_arg(p: argparse.ArgumentParser) -> None:
    """--case FILE.npz, a case file written by ``case export``."""
    add_option(p, "--case", domain="npz in", required=True, metavar="FILE.npz",
               help="case file written by `case export`")  # fmt: skip


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``case`` and its actions ``export``, ``run`` and ``check`` to the parser."""
    cs = add_group(sub, "case",
                   "Export a validation case (model, parameters, every noise draw), run it in "
                   "process, or check the trajectories an engine wrote (README: Engines that run "
                   "the controller themselves).",
                   dest="case_command", metavar="ACTION")  # fmt: skip
    e = add_command(cs, "export", cmd_export, help="write case.npz")
    add_option(e, "--out", domain="npz out", default="case.npz", metavar="FILE.npz",
               help="case file to write")  # fmt: skip
    add_seed_arg(e, 1, "root seed of the noise draws (integer >= 0)")
    add_option(e, "--realizations", domain="case realizations", default=4,
               help="realisations per scenario (count >= 2)")  # fmt: skip
    add_mjcf_arg(e, "a user's CIP model file instead of the shipped one")
    r = add_command(
        cs, "run", cmd_run, help="run a case with a registered engine (reference trajectories)"
    )
    _add_case_arg(r)
    add_engine_arg(r, default="mujoco", help="a registered rigid-body engine")
    add_option(r, "--out", domain="npz out", default="trajectories.npz", metavar="FILE.npz",
                   help="trajectories file to write")  # fmt: skip
    c = add_command(cs, "check", cmd_check, help="validate the trajectories an engine wrote")
    _add_case_arg(c)
    add_option(c, "--trajectories", domain="npz in", required=True, metavar="FILE.npz",
               help="the engine's trajectories (<scenario>/<field> arrays)")  # fmt: skip
    add_engine_arg(c, default="mujoco",
                   help="the registered rigid-body engine whose discretisation the trajectories "
                   "follow: its measured twin and rod tolerances apply")  # fmt: skip
    add_json_arg(c, help="one JSON object on stdout")
    add_ci_options(c, verbose=False)
