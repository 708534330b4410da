"""Parameter-study commands: sweep, sweep-plot, sweep-export."""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from cipcore.atomic import WriteError
from cipcore.params import ParameterError
from validation.cli.args import (
    EXIT_OK,
    add_engine_arg,
    add_force_arg,
    add_seed_arg,
    check_out_dir,
    check_out_file,
    check_work,
    interrupt_signals,
    interrupted_status,
)
from validation.cli.ci_options import progress_enabled
from validation.cli.domains import add_option
from validation.cli.main import add_command, command
from validation.sweeps import (
    METRICS,
    Study,
    SweepPool,
    default_studies_dir,
    parse_grid,
    run_sweep,
    write_sweep_report,
)


def study_path(text: str) -> Path:
    """The TOML file of a study argument: a path, else a shipped study's name."""
    path = Path(text)
    if not path.exists() and (default_studies_dir() / f"{text}.toml").exists():
        path = default_studies_dir() / f"{text}.toml"
    return path


def study_from_args(a: argparse.Namespace) -> Study:
    """The study of a TOML file or shipped study name, overridden by the options."""
    if a.study:
        d = Study.from_toml(study_path(a.study)).as_dict()
    else:
        d = {"name": "cli"}
    cli_grid, cli_set = parse_grid(a.grid or [], "--grid"), parse_grid(a.set or [], "--set")
    for k, v in cli_set.items():
        if len(v) != 1:
            raise ParameterError(f"--set {k} takes one value, got {len(v)}; sweep it with --grid")
    both = set(cli_grid) & set(cli_set)
    if both:
        k = sorted(both)[0]
        raise ParameterError(
            f"--grid {k} and --set {k} contradict: a setting is swept (--grid) or fixed "
            "(--set), not both"
        )
    # the command line overrides the study file: a setting it sweeps is no longer fixed
    grid = {**{k: v for k, v in d.get("grid", {}).items() if k not in cli_set}, **cli_grid}
    fixed = {**{k: v for k, v in d.get("fixed", {}).items() if k not in cli_grid},
             **{k: v[0] for k, v in cli_set.items()}}  # fmt: skip
    for k in ("model", "engine", "realizations", "duration", "seed"):
        if getattr(a, k) is not None:
            d[k] = getattr(a, k)
    if a.compare:
        d["compare"] = list(a.compare)
    if a.target_lambda1 is not None:
        d["gain"] = {**d.get("gain", {}), "target_lambda1": a.target_lambda1}
    if a.metrics:
        d["metrics"] = list(a.metrics)
    d["grid"], d["fixed"] = grid, fixed
    try:
        return Study(**d)
    except ParameterError as exc:  # name a setting as typed: grid.beta -> --grid beta
        text = str(exc)
        for typed, where in ((cli_grid, "grid"), (cli_set, "fixed")):
            option = "--grid" if where == "grid" else "--set"
            for k in typed:
                if text.startswith(f"{where}.{k}"):
                    text = f"{option} {k}" + text[len(where) + 1 + len(k) :]
        raise ParameterError(text) from None


@command(
    "A parameter study: every grid point's metrics, each point saved at once (rerun to resume), "
    "the directory locked while it runs, the dataset in DIR/sweep.nc and a report."
)
def cmd_sweep(a: argparse.Namespace) -> int:
    study = study_from_args(a)
    n_points = len(study.points())
    passes = bool(set(study.metrics) - {"lambda1"}) + ("lambda1" in study.metrics)
    dt = study.fixed.get("dt", min(study.grid.get("dt", [1e-3])))
    check_work(
        "--duration"
        if a.duration is not None or not a.study
        else f"study file {a.study}: [study] duration",
        study.realizations,
        study.duration,
        float(dt),
        runs=n_points * passes,
        force=a.force,
    )
    if study.gain:  # every beta*: gains x realisations x duration per model and delay
        g = study.gain
        check_work(
            f"study file {a.study}: [gain] duration"
            if a.study
            else "--target-lambda1: [gain] duration",
            g["realizations"],
            g["duration"],
            float(dt),
            runs=n_points * g["gains"],
            force=a.force,
        )
    out = check_out_dir("--out", a.out or f"sweep-{study.name}")  # after every check
    finished = []
    t = time.perf_counter()
    with interrupt_signals() as got:
        try:
            rep = run_sweep(
                study,
                out,
                pool=SweepPool(workers=a.workers, scheduler=a.scheduler),
                progress=progress_enabled(),
                on_point=finished.append,
                wait_for_lock=a.wait,
            )
        except WriteError as exc:
            exc.note = (f"the {len(finished)} grid point(s) finished in this run and those of "
                        f"earlier runs are kept in {out / 'points'}; free space and rerun the "
                        "same command to finish")  # fmt: skip
            raise
        except KeyboardInterrupt:
            name, status = interrupted_status(got)
            print(
                f"cip-validate: interrupted by {name}: kept the {len(finished)} grid point(s) "
                f"finished in this run in {out / 'points'}; rerun the same command to "
                "finish the other points",
                file=sys.stderr,
            )
            return status
    try:
        report = write_sweep_report(study, out)
    except WriteError as exc:
        exc.note = (
            f"every grid point is kept in {out / 'points'} and the dataset in {out / 'sweep.nc'}"
        )
        raise
    print(
        f"sweep {study.name}: {rep.computed} points computed, {rep.reused} reused from {out}, "
        f"{time.perf_counter() - t:.1f} s" + (f" ({rep.schedule})" if rep.schedule else "")
    )
    for d in rep.diverged:
        times = ", ".join(f"{t:.4g}" for t in d["times_s"])
        print(
            f"divergence: point {d['point']}: realisations {d['realizations']} diverged "
            f"at t = {times} s (data up to there kept)"
        )
    print(f"dataset: {rep.dataset_path}\nreport: {report}")
    return EXIT_OK


def _dataset_path(text: str) -> Path:
    """``DIR/sweep.nc`` for a sweep directory, else the file itself; one line if absent."""
    path = Path(text)
    if path.is_dir():
        path = path / "sweep.nc"
    if not path.is_file():
        raise ParameterError(f"dataset: no sweep dataset at {text!r}")
    return path


def add_dataset_arg(p: argparse.ArgumentParser) -> None:
    """DATASET: a sweep directory or its sweep.nc (read by :func:`_dataset_path`)."""
    add_option(p, "dataset", domain="dataset", help="sweep directory or sweep.nc")


@command(
    "One sweep metric against a swept parameter: the median over realisations with its "
    "percentile-bootstrap 95 % band (a per-point quantity such as rms_ratio_median with its "
    "stored interval); axes labelled with units."
)
def cmd_sweep_plot(a: argparse.Namespace) -> int:
    from validation.sweeps import plot_metric
    from validation.sweeps.store import read_dataset

    path = _dataset_path(a.dataset)
    png = check_out_file("--out", a.out or f"{a.metric}_vs_{a.x}.png", (".png", ".pdf", ".svg"))
    png = plot_metric(read_dataset(path), a.metric, a.x, png)
    print(png)
    return EXIT_OK


@command(
    "The sweep dataset as a CSV table: one row per grid point and realisation, per-point "
    "quantities repeated; column names carry the units."
)
def cmd_sweep_export(a: argparse.Namespace) -> int:
    """One CSV row per grid point and realisation; columns ``name [units]``."""
    from cipcore.atomic import write_text
    from validation.sweeps.store import read_dataset

    path = _dataset_path(a.dataset)
    csv = check_out_file("--csv", a.csv, (".csv",))
    ds = read_dataset(path)  # checked against its content hash
    df = ds.to_dataframe().reset_index()
    names = {**{c: ds[c].attrs for c in ds.coords}, **{v: ds[v].attrs for v in ds.data_vars}}
    df.columns = [f"{c} [{names[c]['units']}]" if names.get(c, {}).get("units") else c
                  for c in df.columns]  # fmt: skip
    write_text(csv, df.to_csv(index=False))
    print(csv)
    return EXIT_OK


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``sweep``, ``sweep-plot`` and ``sweep-export`` to the parser. The function is long
    because it declares every option of the three commands, one call each.
    """
    p = add_command(sub, "sweep", cmd_sweep)
    add_option(
        p,
        "study",
        domain="text",
        nargs="?",
        help="study TOML file, or a shipped study: "
        + ", ".join(sorted(f.stem for f in default_studies_dir().glob("*.toml"))),
    )
    p.add_argument(
        "--grid",
        action="append",
        metavar="NAME=V1,V2,...",
        help="swept setting (repeatable; units in the README)",
    )
    p.add_argument("--set", action="append", metavar="NAME=V", help="fixed setting (repeatable)")
    add_option(p, "--model", domain="model", help="balancing model (default: the study's)")
    add_option(
        p,
        "--compare",
        domain="compare",
        metavar="REF,OTHER",
        help="two models run with the same seed per realisation, paired ratios and "
        "differences (e.g. single,coupled; default: the study's)",
    )
    add_option(
        p,
        "--target-lambda1",
        domain="target",
        metavar="LAMBDA1",
        help="beta per point set to beta* where the reduced model's lambda1 equals this "
        "(1/s; paper: 5e-4), cached in DIR/gains",
    )
    add_engine_arg(p, default=None)
    add_option(
        p,
        "--metrics",
        domain="metrics",
        help="comma list from " + ",".join(METRICS) + " (default: the study's)",
    )
    add_option(
        p,
        "--realizations",
        domain="study realizations",
        help="realisations per point (count >= 2; default: the study's)",
    )
    add_option(
        p,
        "--duration",
        domain="duration",
        help="simulated time per realisation (s; default: the study's)",
    )
    add_seed_arg(p, None, "study seed (default: the study's)")
    add_option(p, "--out", domain="out dir", metavar="DIR",
               help="sweep directory (default: sweep-NAME)")  # fmt: skip
    add_option(
        p,
        "--workers",
        domain="workers",
        default=None,
        help="local processes (count >= 1; default: chosen by the work: one per core "
        "unless the points are cheaper than starting the processes, then this process)",
    )
    add_option(p, "--scheduler", domain="address", metavar="ADDRESS",
               help="Dask scheduler, e.g. tcp://host:8786")  # fmt: skip
    p.add_argument(
        "--wait",
        action="store_true",
        help="wait for a sweep holding --out to finish instead of failing",
    )
    add_force_arg(p)

    p = add_command(sub, "sweep-plot", cmd_sweep_plot)
    add_dataset_arg(p)
    add_option(p, "--metric", domain="text", required=True,
               help="a variable of the dataset, required")  # fmt: skip
    add_option(p, "--x", domain="text", required=True,
               help="the swept parameter on the x axis, required")  # fmt: skip
    add_option(p, "--out", domain="plot out", metavar="FILE.png",
               help="figure file (default: METRIC_vs_X.png)")  # fmt: skip

    p = add_command(sub, "sweep-export", cmd_sweep_export)
    add_dataset_arg(p)
    add_option(p, "--csv", domain="csv out", required=True, metavar="FILE.csv",
               help="CSV file to write, required")  # fmt: skip
