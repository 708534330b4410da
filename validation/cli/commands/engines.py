"""``cip-validate engines``: every engine through the same checks, one table."""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import sys

from cip.quiet import stdout_to_stderr
from cipcore.registry import engine_names
from validation.cli.args import (
    add_integrator_arg,
    add_json_arg,
    add_no_figures_arg,
    add_profile_arg,
    add_seed_arg,
    add_threads_arg,
    check_out_dir,
)
from validation.cli.ci_options import add_ci_options, junit_file, run_environment
from validation.cli.domains import add_option
from validation.cli.engine_options import INTEGRATORS, add_engine_cmd_arg, register_engine_cmd
from validation.cli.main import add_command, command

EXIT_OK, EXIT_FAIL = 0, 1


def run_record(started: dict | None = None) -> dict:
    """How a run was made, for its report: the command line, the UTC start, the load
    average (1, 5, 15 min) at start and, given ``started`` (this function's value at the
    start), the wall time and the load at the end."""
    import shlex
    import time
    from datetime import UTC, datetime

    load = list(os.getloadavg())
    if started is None:
        return {"command": shlex.join(["cip-validate", *sys.argv[1:]]),
                "started_utc": datetime.now(UTC).strftime("%Y-%m-%d %H:%M"),
                "load_start": load, "t0": time.monotonic(), "cpus": os.cpu_count()}  # fmt: skip
    rec = {k: v for k, v in started.items() if k != "t0"}
    return {**rec, "wall_s": round(time.monotonic() - started["t0"], 1), "load_end": load}


def engine_versions(names: list[str]) -> dict[str, str]:
    """The installed distributions (name -> version) of the modules each engine of
    ``names`` declares it needs (``requires``; an engine not importable here is left out),
    and ``commit``, the short git hash of cipval's source where it is a git checkout."""
    import importlib
    import subprocess
    from importlib.metadata import packages_distributions, version
    from pathlib import Path

    from cipcore.registry import get_engine

    dists = packages_distributions()
    out: dict[str, str] = {}
    for name in names:
        try:
            eng = get_engine(name)
        except Exception:  # not installed here: its row says why
            continue
        for mod in getattr(eng, "requires", ()):
            found = dists.get(mod.split(".")[0], ())
            for dist in found:
                out[dist] = version(dist)
            if not found:  # a module its distribution does not list (pin's, under cmeel)
                v = getattr(importlib.import_module(mod), "__version__", None)
                if v is not None:
                    out[mod] = str(v)
    root = Path(__file__).resolve().parents[3]
    try:
        head = subprocess.run(["git", "-C", str(root), "rev-parse", "--short", "HEAD"],
                              capture_output=True, text=True, timeout=5, check=True)  # fmt: skip
        out["commit"] = head.stdout.strip()
    except (OSError, subprocess.SubprocessError):
        pass
    return out


@command(
    "Run every registered engine (or --engines) through the checks of `cip-validate run` (its "
    "exact twin, the delay, the rod, the declared model, the agreement with the reduced reference "
    "on the same seeds) and list them in one table with throughput (realisation-steps/s) in "
    "DIR/report.md and report.html; an engine not installed here is skipped with the reason."
)
def cmd_engines(a: argparse.Namespace) -> int:
    from cipcore.driver import default_threads
    from cipcore.params import ParameterError
    from validation.cli.args import interrupt_signals, interrupted_status
    from validation.engines import (
        EnginesInterrupted,
        EnginesSetting,
        compare_engines,
        parse_engines,
    )

    given = a.engines  # names of the registry, each once (the "engines" domain)
    if given is not None and "all" in given and len(given) > 1:
        raise ParameterError(f"--engines: 'all' names every engine; give it alone, got {given}")
    cmd_engine = register_engine_cmd(a.engine_cmd, a.engine_timeout)
    if cmd_engine is not None:  # the reference, MuJoCo (the speed baseline) and the command
        listed = given or ("reduced", "mujoco")
        names = [n for n in parse_engines(",".join(listed)) if n != cmd_engine]
        names.append(cmd_engine)
    else:
        names = parse_engines(None if given is None else ",".join(given))
    out = check_out_dir("--out", a.out)  # checked before any work
    junit = junit_file(a)
    quiet = a.json or a.quiet
    say = (lambda line: None) if quiet else (lambda line: print(line, file=sys.stderr))
    started = run_record()
    setting = EnginesSetting(a.profile, a.seed, a.threads, a.jobs or default_threads(),
                             a.integrator, a.selftest)  # fmt: skip
    if setting.jobs > 1:  # engines share the device: JAX here must not take 75 % of a GPU
        from validation.engine_jobs import share_device

        share_device(os.environ)
    stopped = None  # (signal name, exit status) when interrupted: the finished rows are kept
    with interrupt_signals() as got:  # a later signal cannot break off the writing
        # an engine's import banner (warp's) must not corrupt the JSON on stdout
        with stdout_to_stderr() if a.json else contextlib.nullcontext():
            try:
                results = compare_engines(names, setting, progress=say)
            except EnginesInterrupted as exc:
                results, stopped = exc.results, interrupted_status(got)
        for _ in range(2):  # a first signal while writing: once more (later ones are ignored)
            try:
                env = run_environment()  # versions, platform, fingerprint: computed once
                versions = {**env["versions"], **engine_versions(names)}
                results["run"] = {**run_record(started), "versions": versions}
                _write(a, results, env, out, junit)
                break
            except KeyboardInterrupt:
                stopped = stopped or interrupted_status(got)
    if stopped is not None:
        done = [r["engine"] for r in results["engines"] if r["status"] != "interrupted"]
        print(f"cip-validate: interrupted by {stopped[0]}: kept {len(done)} of "
              f"{len(results['engines'])} engines ({', '.join(done) or 'none'}) in "
              f"{out / 'results.json'} (partial)", file=sys.stderr)  # fmt: skip
        return stopped[1]
    # an engine that raised or whose process died (an --engine-cmd program that exits) is
    # a row of its own, "crashed" with the reason, and every other row is written
    rows = {r["engine"]: r for r in results["engines"]}
    for name in results["crashed"]:
        print(f"cip-validate: an engine crashed: {name}: {rows[name]['reason']}", file=sys.stderr)
    if results["crashed"]:
        from validation.cli.exitcodes import EXIT_CRASH

        return EXIT_CRASH
    return EXIT_OK if results["status"] != "fail" else EXIT_FAIL


def _write(a: argparse.Namespace, results: dict, env: dict, out, junit) -> None:
    """The reports in ``out``, the JUnit file, and the JSON document or the table on stdout."""
    from validation.engines import write_engine_reports

    write_engine_reports(results, out, figures=not a.no_figures)
    if junit:
        from validation.cli.junit import engines_cases, write_junit

        write_junit(engines_cases(results), junit)
    if a.json:
        from validation import engines as cross
        from validation.report.document import jsonable

        # the engine's own twin and rod tolerances are in its row; the run's checks in
        # each row's "checks" carry theirs
        tolerances = {"linearization_residual": cross.LINEARIZATION_TOLERANCE}
        doc = {"cipval_engines": 1, **results, "tolerances": tolerances, **env}
        print(json.dumps(jsonable(doc)))
    else:
        _print_table(results["engines"])
        print(f"report: {out / 'report.md'}")


def _print_table(rows: list[dict]) -> None:
    """One line per engine: verdict, distance, throughput (or why it has no verdict)."""
    from validation.engines import has_verdict

    for r in rows:
        if not has_verdict(r):
            print(f"{r['engine']:12s} {r['status']}: {r['reason']}")
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


def add_engines_command(sub: argparse._SubParsersAction) -> None:
    """Add ``engines`` to the parser."""
    p = add_command(sub, "engines", cmd_engines)
    registered = ", ".join(engine_names())
    add_option(p, "--engines", domain="engines", metavar="A,B,...",
               help=f"engines to validate or all (default: all: {registered})")  # fmt: skip
    add_profile_arg(p, "sizes of the checks (the profiles of `cip-validate run`)")
    add_seed_arg(p, None, "root seed of every noise draw (integer >= 0; default: the profile's)")
    add_integrator_arg(p, "MuJoCo integrator for engines that follow the model file "
                       f"({', '.join(INTEGRATORS)}; default: the file's)")  # fmt: skip
    p.add_argument("--selftest", action="store_true",
                   help="also inject the fault catalogue into each rigid-body engine")  # fmt: skip
    add_threads_arg(p)
    add_option(p, "--jobs", domain="workers", default=None, metavar="N",
               help="engines checked at a time, each in a process of its own (count >= 1; "
               "default: one per core); the throughputs are measured first, one engine at a "
               "time; results do not depend on it")  # fmt: skip
    add_option(p, "--out", domain="out dir", default="cip-engines-out", metavar="DIR",
                   help="output directory (created if absent; must be writable)")  # fmt: skip
    add_no_figures_arg(p, "skip the speed-accuracy figure")
    add_json_arg(p)
    add_ci_options(p, verbose=False)
    add_engine_cmd_arg(p)
