"""The validation suite's commands: run, baseline."""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

from cipcore.atomic import WriteError, write_bytes
from cipcore.params import ParameterError
from validation.checks.divergence import group_lines
from validation.cli.args import (
    EXIT_OK,
    add_mjcf_arg,
    add_no_figures_arg,
    add_profile_arg,
    add_seed_arg,
    add_threads_arg,
    check_out_dir,
    check_out_file,
    interrupt_signals,
    interrupted_status,
)
from validation.cli.ci_options import add_ci_options, junit_file, progress_enabled
from validation.cli.domains import add_option
from validation.cli.engine_options import add_engine_options, check_engine_options
from validation.cli.main import add_command, command
from validation.profiles import PROFILES


def read_results(path: str, option: str) -> dict:
    """A results.json written by cip-validate, or a one-line usage error naming ``option``."""
    p = Path(path)
    if not p.is_file():
        raise ParameterError(f"{option}: no such file {path!r}")
    try:
        results = json.loads(p.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise ParameterError(f"{option}: {path!r} is not JSON ({exc})") from None
    if not isinstance(results, dict) or results.get("cipval_results") != 1:
        raise ParameterError(f"{option}: {path!r} is not a cip-validate results file")
    if results.get("partial"):
        raise ParameterError(f"{option}: {path!r} is a partial run; finish it with --resume")
    return results


def _say(text: str) -> None:
    from tqdm.auto import tqdm

    tqdm.write(text, file=sys.stderr)


def _quiet_say(text: str) -> None:
    return None


@command(
    "Every agreement check, the paper table, the figures and the report.  Each finished stage is "
    "saved in --out at once (results.json marked partial until the end); --resume reuses them."
)
def cmd_run(a: argparse.Namespace) -> int:
    """The function is long because it turns every way a run can end into its exit code and one
    message.
    """

    from cip.mjcf_params import model_files
    from cipcore.scenario import EngineTarget
    from validation.cli.checklog import regression_log
    from validation.cli.exitcodes import EXIT_CRASH, run_status
    from validation.cli.junit import run_cases, write_junit
    from validation.regression.baseline import choose_mode
    from validation.report.document import (
        compare_with_baseline,
        jsonable,
        summary_table,
        write_reports,
    )
    from validation.run import (
        STAGES,
        RunInterrupted,
        RunSetting,
        StageCrashed,
        compile_note,
        run_validation,
    )

    baseline = read_results(a.baseline, "--baseline") if a.baseline else None
    if baseline is not None and baseline.get("profile") != a.profile:
        raise ParameterError(
            f"--baseline: {a.baseline!r} was made with profile {baseline.get('profile')!r}, "
            f"this run uses {a.profile!r}"
        )
    profile = PROFILES[a.profile]
    if a.seed is not None:
        from dataclasses import replace

        profile = replace(profile, seed=a.seed)
    if (
        baseline is not None
        and baseline.get("settings", {}).get("seed", profile.seed) != profile.seed
    ):
        raise ParameterError(
            f"--baseline: {a.baseline!r} was made with seed {baseline['settings']['seed']}, "
            f"this run uses --seed {profile.seed}"
        )
    files = model_files(a.mjcf)  # a bad model file is refused before any work
    if a.resume and getattr(a, "engine_cmd", None) is not None:
        raise ParameterError(
            "--resume with --engine-cmd: the finished stages cannot be tied to an external "
            "program's build; rerun without --resume"
        )
    check_engine_options(a)
    if baseline is not None:
        made = baseline.get("engine") or {}  # baselines without the record are MuJoCo's
        b_engine, b_integ = made.get("name", "mujoco"), made.get("integrator_requested")
        if (b_engine, b_integ) != (a.engine, a.integrator):
            raise ParameterError(
                f"--baseline: {a.baseline!r} was made with engine {b_engine!r} (integrator "
                f"{b_integ or 'of the file'}), this run uses {a.engine!r} (integrator "
                f"{a.integrator or 'of the file'})"
            )
    out = check_out_dir("--out", a.out)
    junit = junit_file(a)
    if baseline is not None and a.baseline_mode == "auto":  # other models: refused before work
        from validation.regression.fingerprint import model_digests

        choose_mode({"versions": baseline.get("versions"), "model_files": files,
                     "fingerprint": {"model_digests": model_digests(files)}}, baseline)  # fmt: skip
    say = _quiet_say if a.quiet else _say
    note = compile_note()
    if note:
        say(note)

    def on_stage(name: str, seconds: float, reused: bool) -> None:
        how = "reused from the last run" if reused else f"{seconds:.1f} s"
        say(f"stage {STAGES.index(name) + 1}/{len(STAGES)} {name}: {how}")

    with interrupt_signals() as got:
        try:
            setting = RunSetting(
                profile,
                EngineTarget(a.engine, a.integrator, files),
                workers=a.workers,
                figures=not a.no_figures,
                resume=a.resume,
                progress=progress_enabled(a.quiet),
            )
            results = run_validation(
                setting, out, on_stage=on_stage, interrupted=lambda: got["signal"] is not None
            )
        except WriteError as exc:
            exc.note = (f"the stages finished before it are kept in {out / 'stages'}; free "
                        "space and rerun with --resume to finish")  # fmt: skip
            raise
        except RunInterrupted as exc:
            kept = ", ".join(exc.kept) or "none"
            name, status = interrupted_status(got)
            print(
                f"cip-validate: interrupted by {name}: kept {len(exc.kept)} of {len(STAGES)} "
                f"stages ({kept}) in {out / 'results.json'} (partial); rerun with --resume "
                "to finish",
                file=sys.stderr,
            )
            return status
        except StageCrashed as exc:
            from cipcore.params import EngineError

            if isinstance(exc.__cause__, EngineError):  # the engine broke, whatever the stage
                what = " ".join(str(exc.__cause__).split())
            else:
                what = f"stage {exc.stage!r} crashed ({exc.error})"
            print(f"cip-validate: {what}; kept {len(exc.kept)} of {len(STAGES)} stages in "
                  f"{out / 'results.json'} (partial, naming the stage)",
                  file=sys.stderr)  # fmt: skip
            if junit:
                write_junit(run_cases(json.loads((out / "results.json").read_text())), junit)
            return EXIT_CRASH
        checks_failed = results["status"] == "fail"
        regression = None
        if baseline:
            mode, why = choose_mode(jsonable(results), baseline, a.baseline_mode)
            regression = compare_with_baseline(results, baseline, mode)
        if regression:
            failed = [c for c in regression if c.status == "fail"]
            results["regression"] = {"baseline": str(a.baseline), "checked": len(regression),
                                     "mode": mode, "mode_reason": why,
                                     "failed": [c.as_dict() for c in failed]}  # fmt: skip
            if failed:
                results["status"] = "fail"
        try:
            write_reports(results, out, regression)
        except WriteError as exc:
            exc.note = (f"every stage is kept in {out / 'stages'}; free space and rerun with "
                        "--resume to write the reports")  # fmt: skip
            raise
    if junit:
        write_junit(run_cases(jsonable(results), regression or []), junit, results["elapsed_s"])
    moved = regression is not None and any(c.status == "fail" for c in regression)
    if not a.quiet or checks_failed:
        print(summary_table(results))
    for line in group_lines(results.get("divergence", [])):
        print(f"divergence: {line}")
    if regression is not None:
        nfail = sum(c.status == "fail" for c in regression)
        same = "reproduced" if mode == "exact" else "within tolerance"
        print(f"regression vs {a.baseline}: {mode} mode ({why}): "
              f"{len(regression) - nfail} of {len(regression)} numbers {same}"
              + (f", {nfail} moved:" if nfail else ""))  # fmt: skip
        names = [c["name"] for c in results["checks"]]
        for line in regression_log(regression, names, verbose=a.verbose):
            print(line)
    print(f"report: {out / 'report.md'}, {out / 'report.html'}, {out / 'results.json'}"
          + (f", {junit}" if junit else ""))  # fmt: skip
    return run_status(checks_failed, moved)


@command(
    "Run the suite without figures (or take --from) and write the results as a regression baseline."
)
def cmd_baseline(a: argparse.Namespace) -> int:
    from cipcore.scenario import EngineTarget
    from validation.report.document import write_json
    from validation.run import RunInterrupted, RunSetting, run_validation

    out = check_out_file("--out", a.out, (".json",))
    check_engine_options(a)
    if a.from_results:
        read_results(a.from_results, "--from")
        write_bytes(out, Path(a.from_results).read_bytes())
    else:
        with interrupt_signals() as got, tempfile.TemporaryDirectory() as tmp:
            try:
                setting = RunSetting(PROFILES[a.profile], EngineTarget(a.engine, a.integrator),
                                     workers=a.workers, figures=False,
                                     progress=progress_enabled())  # fmt: skip
                results = run_validation(setting, Path(tmp),
                                         interrupted=lambda: got["signal"] is not None)  # fmt: skip
            except RunInterrupted:
                name, status = interrupted_status(got)
                print(
                    f"cip-validate: interrupted by {name}: no baseline written (run "
                    "`cip-validate run` and `baseline --from` to keep stages)",
                    file=sys.stderr,
                )
                return status
        write_json(results, out)
    print(f"baseline written: {out}")
    return EXIT_OK


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``run`` and ``baseline`` to the parser."""
    p = add_command(sub, "run", cmd_run)
    add_profile_arg(
        p,
        "run size: smoke (seconds, every code path), quick (every check, minutes), paper (the "
        "paper's counts and durations), robustness (paper, plus the full grid of estimator "
        "choices)",
    )
    add_option(
        p,
        "--out",
        domain="out dir",
        default="cip-validate-out",
        metavar="DIR",
        help="output directory (created if absent; must be writable)",
    )
    add_option(
        p,
        "--baseline",
        domain="json in",
        metavar="FILE",
        help="results.json to compare with (regression run)",
    )
    add_option(
        p,
        "--baseline-mode",
        domain="baseline mode",
        default="auto",
        help="exact: every number to 1e-12 relative; roundoff: every number to 1e-9 "
        "relative + 1e-12; statistical: paired tolerances; auto (default): exact when package "
        "versions, CPU instruction set and numpy/BLAS build match, roundoff when only the "
        "CPU or BLAS differ, statistical when a version differs",
    )
    add_ci_options(p)
    add_mjcf_arg(
        p,
        "a user's CIP model file instead of the shipped models/cip_<model>.xml (repeat for "
        "single and coupled; the model is read from the file)",
    )
    add_threads_arg(p, suite=True)
    p.add_argument(
        "--resume",
        action="store_true",
        help="reuse the stages an interrupted run with the same profile left in --out",
    )
    add_no_figures_arg(p, "skip the figures")
    add_engine_options(p)
    add_seed_arg(p, None, "root seed of every stage (integer >= 0; default: the profile's, 2011)")

    p = add_command(sub, "baseline", cmd_baseline)
    add_profile_arg(p, "run size")
    add_option(
        p,
        "--out",
        domain="json out",
        default="baseline.json",
        metavar="FILE.json",
        help="baseline file to write (.json, in a writable directory)",
    )
    add_option(
        p,
        "--from",
        domain="json in",
        dest="from_results",
        metavar="RESULTS.json",
        help="use an existing results.json instead of running",
    )
    add_threads_arg(p, suite=True)
    add_engine_options(p)
