"""Subcommands beyond the reduced model's own: simulate, linearize, run, baseline."""

from __future__ import annotations

import argparse

import numpy as np

from reduced.params import ParameterError
from validation.cli import EXIT_OK, _dump, _model_args, _params, _run_args


def cmd_simulate(a: argparse.Namespace) -> int:
    params = _params(a)
    if a.engine == "mujoco":
        from cip.simulate import simulate_full

        phys = _physical(a)
        traj = simulate_full(
            a.model, params, a.duration, a.realizations, a.seed, amplitude=a.amplitude,
            physical=phys, decimate=a.decimate, threads=a.threads, progress=True,
        )  # fmt: skip
    else:
        from reduced.simulate import simulate

        traj = simulate(
            a.model, params, a.duration, a.realizations, a.seed, amplitude=a.amplitude,
            stepper=a.stepper, decimate=a.decimate, threads=a.threads, progress=True,
        )  # fmt: skip
    if not a.out.endswith(".npz"):
        raise ParameterError(f"--out must name a .npz file, got {a.out!r}")
    traj.save_npz(a.out)
    e = traj["balancing_error"]
    summary = {
        "out": a.out,
        "engine": a.engine,
        "model": a.model,
        "shape": list(e.shape),
        "rms_balancing_error": float(np.sqrt(np.mean(e.astype(float) ** 2))),
        "max_abs_angle": traj.attrs.get("max_abs_angle"),
        "left_small_angle": traj.attrs.get("left_small_angle"),
    }
    print(_dump(summary) if a.json else "\n".join(f"{k}: {v}" for k, v in summary.items()))
    return EXIT_OK


def _physical(a: argparse.Namespace):
    from cip.model import CIPParams

    return CIPParams.from_reduced(
        _params(a, beta=0.0), rod_length=a.rod_length, mass_ratio=a.mass_ratio
    )


def cmd_linearize(a: argparse.Namespace) -> int:
    from cip.linearize import linearize, transition_check

    phys = _physical(a)
    lin = linearize(a.model, phys)
    out = {
        "model": a.model,
        "coordinates": lin.labels,
        "A_full": lin.A_full,
        "A_reduced": lin.A_reduced,
        "A_difference": lin.A_diff,
        "A_predicted_extra": lin.A_extra,
        "B_full": lin.B_full,
        "B_reduced": lin.B_reduced,
        "residual_after_extra_terms": lin.residual,
        "rod_stiffness": lin.rod_stiffness,
        "rod_damping": lin.rod_damping,
        "implied_reduced": phys.implied_reduced(),
        "mjd_transitionFD_check": transition_check(a.model, phys),
    }
    if a.json:
        print(_dump(out))
        return EXIT_OK
    np.set_printoptions(precision=6, suppress=True, linewidth=140)
    print(f"{a.model} CIP linearised about upright; x = ({', '.join(lin.labels)}); u = F/M")
    for key in ("A_full", "A_reduced", "A_difference", "A_predicted_extra", "B_full", "B_reduced"):
        print(f"\n{key}:\n{np.asarray(out[key])}")
    print(f"\nmax |A_full - A_reduced - predicted extra| = {lin.residual:.3g} 1/s^2")
    if lin.rod_stiffness is not None:
        print(f"rod constraint on delta: stiffness {lin.rod_stiffness:.4g} 1/s^2, "
              f"damping {lin.rod_damping:.4g} 1/s")  # fmt: skip
    print(f"mjd_transitionFD vs Euler map of A: {out['mjd_transitionFD_check']:.3g}")
    print("implied reduced parameters:", phys.implied_reduced())
    return EXIT_OK


def add_commands(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("linearize", help="A, B of the MuJoCo CIP beside the reduced model's")
    _model_args(p, beta=False)
    p.add_argument("--rod-length", type=float, default=1.0, help="rod length l (m)")
    p.add_argument("--mass-ratio", type=float, default=1e-3, help="bob / cart mass m/M")
    p.add_argument("--json", action="store_true")
    p.set_defaults(func=cmd_linearize)
    add_run_commands(sub)
    add_sweep_commands(sub)

    p = sub.add_parser("simulate", help="time series of either engine to a .npz file")
    _model_args(p)
    _run_args(p, duration=10.0, realizations=4)
    p.add_argument("--engine", choices=("reduced", "mujoco"), default="reduced")
    p.add_argument("--stepper", choices=("semi-implicit", "explicit"), default="semi-implicit",
                   help="reduced engine only")  # fmt: skip
    p.add_argument("--amplitude", type=float, default=0.01, help="initial balancing error (m)")
    p.add_argument("--rod-length", type=float, default=1.0, help="rod length l (m), mujoco only")
    p.add_argument("--mass-ratio", type=float, default=1e-3, help="bob / cart mass m/M, mujoco")
    p.add_argument("--decimate", type=int, default=1, help="record every N-th step")
    p.add_argument("--out", required=True, metavar="FILE.npz")
    p.add_argument("--json", action="store_true")
    p.set_defaults(func=cmd_simulate)


# ------------------------------------------------------------------ run
def _profile(name: str):
    from validation.profiles import PROFILES

    return PROFILES[name]


def _read_results(path: str, option: str) -> dict:
    """A results.json written by cip-validate, or a one-line usage error naming ``option``."""
    import json
    from pathlib import Path

    p = Path(path)
    if not p.is_file():
        raise ParameterError(f"{option}: no such file {path!r}")
    try:
        results = json.loads(p.read_text())
    except json.JSONDecodeError as exc:
        raise ParameterError(f"{option}: {path!r} is not JSON ({exc.msg})") from None
    if not isinstance(results, dict) or results.get("cipval_results") != 1:
        raise ParameterError(f"{option}: {path!r} is not a cip-validate results file")
    return results


def cmd_run(a: argparse.Namespace) -> int:
    from pathlib import Path

    from validation.harness import run_validation
    from validation.report import compare_with_baseline, summary_table, write_reports

    baseline = _read_results(a.baseline, "--baseline") if a.baseline else None
    if baseline is not None and baseline.get("profile") != a.profile:
        raise ParameterError(
            f"--baseline: {a.baseline!r} was made with profile {baseline.get('profile')!r}, "
            f"this run uses {a.profile!r}"
        )
    if a.workers is not None and a.workers < 1:
        raise ParameterError(f"--workers must be an integer >= 1, got {a.workers}")
    out = Path(a.out)
    results = run_validation(_profile(a.profile), out, workers=a.workers, progress=True,
                             figures=not a.no_figures)  # fmt: skip
    regression = compare_with_baseline(results, baseline) if baseline else None
    if regression:
        failed = [c for c in regression if c.status == "fail"]
        results["regression"] = {"baseline": str(a.baseline), "checked": len(regression),
                                 "failed": [c.as_dict() for c in failed]}  # fmt: skip
        if failed:
            results["status"] = "fail"
    write_reports(results, out, regression)
    print(summary_table(results, [c for c in regression or [] if c.status != "pass"]))
    if regression is not None:
        nfail = sum(c.status == "fail" for c in regression)
        print(f"regression vs {a.baseline}: {len(regression) - nfail} of {len(regression)} "
              "numbers unchanged within 4 combined standard errors")  # fmt: skip
    print(f"report: {out / 'report.md'}, {out / 'report.html'}, {out / 'results.json'}")
    return 1 if results["status"] == "fail" else 0


def cmd_baseline(a: argparse.Namespace) -> int:
    import shutil
    from pathlib import Path

    out = Path(a.out)
    if a.from_results:
        _read_results(a.from_results, "--from")
        shutil.copyfile(a.from_results, out)
    else:
        import tempfile

        from validation.harness import run_validation
        from validation.report import write_json

        with tempfile.TemporaryDirectory() as tmp:
            results = run_validation(_profile(a.profile), Path(tmp), workers=a.workers,
                                     progress=True, figures=False)  # fmt: skip
        write_json(results, out)
    print(f"baseline written: {out}")
    return 0


def add_run_commands(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("run", help="the validation suite: checks, paper table, figures, report")
    p.add_argument("--profile", choices=("quick", "paper", "smoke", "robustness"), default="quick")
    p.add_argument("--out", default="cip-validate-out", metavar="DIR")
    p.add_argument("--baseline", metavar="FILE", help="results.json to compare with")
    p.add_argument("--workers", type=int, default=None, help="threads (default: all cores)")
    p.add_argument("--no-figures", action="store_true", help="skip the figures")
    p.set_defaults(func=cmd_run)

    p = sub.add_parser("baseline", help="write a baseline results file for --baseline")
    p.add_argument("--profile", choices=("quick", "paper", "smoke", "robustness"), default="quick")
    p.add_argument("--out", default="baseline.json", metavar="FILE")
    p.add_argument("--from", dest="from_results", metavar="RESULTS.json",
                   help="use an existing results.json instead of running")  # fmt: skip
    p.add_argument("--workers", type=int, default=None)
    p.set_defaults(func=cmd_baseline)


# ---------------------------------------------------------------- sweep
def cmd_sweep(a: argparse.Namespace) -> int:
    import time
    from pathlib import Path

    from validation.sweep import (
        Study,
        default_studies_dir,
        parse_grid,
        run_sweep,
        write_sweep_report,
    )

    if a.study:
        path = Path(a.study)
        if not path.exists() and (default_studies_dir() / f"{a.study}.toml").exists():
            path = default_studies_dir() / f"{a.study}.toml"
        study = Study.from_toml(path)
        d = study.as_dict()
    else:
        d = {"name": "cli"}
    grid = {**d.get("grid", {}), **parse_grid(a.grid or [])}
    fixed = {**d.get("fixed", {}), **parse_grid(a.set or [])}
    fixed = {k: v[0] if isinstance(v, list) and len(v) == 1 else v for k, v in fixed.items()}
    for k in ("model", "engine", "realizations", "duration", "seed"):
        if getattr(a, k) is not None:
            d[k] = getattr(a, k)
    if a.metrics:
        d["metrics"] = [m.strip() for m in a.metrics.split(",") if m.strip()]
    d["grid"], d["fixed"] = grid, fixed
    study = Study(**d)
    if a.workers is not None and a.workers < 1:
        raise ParameterError(f"--workers must be an integer >= 1, got {a.workers}")
    out = Path(a.out or f"sweep-{study.name}")
    t = time.perf_counter()
    rep = run_sweep(study, out, workers=a.workers, scheduler=a.scheduler, progress=True)
    report = write_sweep_report(study, out)
    print(f"sweep {study.name}: {rep.computed} points computed, {rep.reused} reused from {out}, "
          f"{time.perf_counter() - t:.1f} s")  # fmt: skip
    print(f"dataset: {rep.dataset_path}\nreport: {report}")
    return EXIT_OK


def cmd_sweep_plot(a: argparse.Namespace) -> int:
    from pathlib import Path

    import xarray as xr

    from validation.sweep import plot_metric

    path = Path(a.dataset)
    if path.is_dir():
        path = path / "sweep.nc"
    if not path.is_file():
        raise ParameterError(f"no sweep dataset at {a.dataset!r}")
    with xr.open_dataset(path, engine="scipy") as ds:
        png = plot_metric(ds.load(), a.metric, a.x, Path(a.out or f"{a.metric}_vs_{a.x}.png"))
    print(png)
    return EXIT_OK


def add_sweep_commands(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("sweep", help="parameter study over a grid (resumable; local or Dask)")
    p.add_argument("study", nargs="?", help="study TOML file, or a shipped study: "
                   "rod_length, engine_settings")  # fmt: skip
    p.add_argument("--grid", action="append", metavar="NAME=V1,V2,...", help="swept setting")
    p.add_argument("--set", action="append", metavar="NAME=V", help="fixed setting")
    p.add_argument("--model", choices=("single", "coupled"))
    p.add_argument("--engine", choices=("reduced", "mujoco"))
    p.add_argument("--metrics", help="comma list: lambda1,rms,max_angle,agreement,tau_hat,slopes")
    p.add_argument("--realizations", type=int)
    p.add_argument("--duration", type=float)
    p.add_argument("--seed", type=int)
    p.add_argument("--out", metavar="DIR", help="sweep directory (default sweep-NAME)")
    p.add_argument("--workers", type=int, default=None,
                   help="local processes (default: one per core)")  # fmt: skip
    p.add_argument("--scheduler", metavar="ADDRESS", help="Dask scheduler, e.g. tcp://host:8786")
    p.set_defaults(func=cmd_sweep)

    p = sub.add_parser("sweep-plot", help="a sweep metric against a parameter, with 95% bands")
    p.add_argument("dataset", help="sweep directory or sweep.nc")
    p.add_argument("--metric", required=True)
    p.add_argument("--x", required=True, help="the swept parameter on the x axis")
    p.add_argument("--out", metavar="FILE.png")
    p.set_defaults(func=cmd_sweep_plot)
