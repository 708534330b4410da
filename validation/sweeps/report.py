"""Plots and the Markdown report of a sweep dataset."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from cipcore.atomic import write_text, write_with
from cipcore.params import ParameterError

from .store import is_number
from .study import Study

LABELS = {
    "lambda1": "largest Lyapunov exponent lambda1 (1/s)",
    "rms": "log10 RMS of the balancing error (log10 m)",
    "max_angle": "largest |theta| (rad)",
    "agreement": "relative L2 distance to the reduced model (first 10 s)",
    "tau_hat": "median first STCC peak tau_hat (s)",
    "divergence_time": "time a realisation diverged (s)",
    "rod_length_ratio": "rod length l / pendulum length L",
    "mass_ratio": "bob / cart mass m/M",
    "dt": "time step (s)",
    "amplitude": "initial balancing error (m)",
}


def mean_ci(ds, name: str):
    """Mean over realisations and its Student-t 95 % half-width (NaNs ignored)."""
    import scipy.stats

    a = ds[name]
    if "realization" not in a.dims:
        return a, a * np.nan
    n = a.count("realization")
    m = a.mean("realization")
    sd = a.std("realization", ddof=1)
    t = scipy.stats.t.ppf(0.975, np.maximum(n - 1, 1))
    return m, t * sd / np.sqrt(n)


def plot_metric(ds, metric: str, x: str, path: Path) -> Path:
    """A metric against one swept parameter, one line per value of the others,
    with 95 % confidence bands over realisations."""
    from ..plots import plt

    if metric not in ds:
        raise ParameterError(
            f"--metric: {metric!r} not in the sweep; has {', '.join(ds.data_vars)}"
        )
    if x not in ds.dims or x == "realization":
        dims = [d for d in ds.dims if d != "realization"]
        raise ParameterError(f"--x: {x!r} is not a swept parameter; swept: {', '.join(dims)}")
    m, h = mean_ci(ds, metric)
    others = [d for d in m.dims if d != x]
    fig, ax = plt.subplots(figsize=(6.4, 4.0), constrained_layout=True)
    stacked = m.stack(line=others) if others else m.expand_dims(line=[0])
    hw = h.stack(line=others) if others else h.expand_dims(line=[0])
    xs = ds[x].values
    for k in range(stacked.sizes["line"]):
        y = stacked.isel(line=k).transpose(x).values
        e = hw.isel(line=k).transpose(x).values
        vals = np.atleast_1d(stacked["line"].values[k])
        label = ", ".join(f"{d}={v}" for d, v in zip(others, vals, strict=False)) or metric
        ax.plot(xs, y, "o-", ms=3, label=label)
        ax.fill_between(xs, y - e, y + e, alpha=0.2)
    if (
        np.issubdtype(np.asarray(xs).dtype, np.number)
        and np.all(xs > 0)
        and xs.max() / xs.min() > 20
    ):
        ax.set_xscale("log")
    ax.set_xlabel(LABELS.get(x, x))
    ax.set_ylabel(LABELS.get(metric, metric))
    n = ds.sizes.get("realization", 1)
    ax.set_title(f"mean over realisations, 95% band ({n} realisations)", fontsize=8)
    ax.legend(fontsize=7)
    write_with(path, lambda tmp: fig.savefig(tmp, dpi=110, format=Path(path).suffix[1:]))
    plt.close(fig)
    return path


def write_sweep_report(study: Study, out_dir: Path) -> Path:
    """DIR/report.md: one figure per metric against the first swept parameter, and a table."""
    import xarray as xr

    out_dir = Path(out_dir)
    with xr.open_dataset(out_dir / "sweep.nc", engine="scipy") as ds:
        ds = ds.load()
    x = next(iter(study.grid))
    lines = [f"# Sweep {study.name}", "",
             f"{study.model} model, engine {study.engine}, {study.realizations} realisations x "
             f"{study.duration:g} s per point, seed {study.seed} "
             f"({'common random numbers' if study.common_random_numbers else 'seed per point'}).",
             "", f"Fixed: {json.dumps(study.fixed)}", ""]  # fmt: skip
    per = [m for m in ds.data_vars if "realization" in ds[m].dims and m != "divergence_time"]
    for metric in per:
        png = plot_metric(ds, metric, x, out_dir / f"sweep_{metric}.png")
        lines += [f"![{metric}]({png.name})", ""]
    dims = [d for d in study.grid]
    head = dims + [f"{m} (mean +- 95%)" for m in per]
    if "divergence_time" in ds:
        head.append("diverged (realisations)")
    lines += ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for point in study.points():
        sel = {k: (float(v) if is_number(v) else str(v)) for k, v in point.items()}
        cells = [str(point[k]) for k in dims]
        for m in per:
            mean, hw = mean_ci(ds, m)
            cells.append(f"{float(mean.sel(sel)):.4g} +- {float(hw.sel(sel)):.2g}")
        if "divergence_time" in ds:
            t = ds["divergence_time"].sel(sel).values
            cells.append(str(int(np.isfinite(t).sum())))
        lines.append("| " + " | ".join(cells) + " |")
    path = out_dir / "report.md"
    write_text(path, "\n".join(lines) + "\n")
    return path
