"""Plots and the Markdown report of a sweep dataset."""

from __future__ import annotations

import json
import warnings
from pathlib import Path

import numpy as np

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


#: metrics that are never negative and heavy-tailed over realisations: drawn as the median
#: with the central 50 % and 90 % of the realisations (a mean +- CI band would cross 0)
QUANTILE_METRICS = {"max_angle", "agreement", "tau_hat", "divergence_time"}


def _lines(a, x: str, others: list[str]):
    """(label, DataArray over (x[, realization])) per combination of the other swept values."""
    if not others:
        return [("", a)]
    st = a.stack(line=others)
    out = []
    for k in range(st.sizes["line"]):
        vals = np.atleast_1d(st["line"].values[k])
        label = ", ".join(f"{d}={v}" for d, v in zip(others, vals, strict=False))
        out.append((label, st.isel(line=k)))
    return out


def plot_metric(ds, metric: str, x: str, path: Path) -> Path:
    """A metric against one swept parameter, one line per value of the others.

    Metrics in :data:`QUANTILE_METRICS` (positive, heavy-tailed): the median
    over realisations with the central 50 % and 90 % of them as bands, on a
    log axis where the medians span more than a decade, angles
    capped at pi (the pendulum's largest |theta|); the realisations that
    diverged (``divergence_time`` finite) are counted per line in the legend.
    Other metrics: the mean with its Student-t 95 % confidence band.
    """
    from ..plots import plt

    if metric not in ds:
        raise ParameterError(
            f"--metric: {metric!r} not in the sweep; has {', '.join(ds.data_vars)}"
        )
    if x not in ds.dims or x == "realization":
        dims = [d for d in ds.dims if d != "realization"]
        raise ParameterError(f"--x: {x!r} is not a swept parameter; swept: {', '.join(dims)}")
    quantiles = metric in QUANTILE_METRICS and "realization" in ds[metric].dims
    others = [d for d in ds[metric].dims if d not in (x, "realization")]
    fig, ax = plt.subplots(figsize=(6.4, 4.0), constrained_layout=True)
    xs = ds[x].values
    n = ds.sizes.get("realization", 1)
    div = ds["divergence_time"] if "divergence_time" in ds else None
    div_lines = dict(_lines(div, x, others)) if div is not None else {}
    medians = []
    if quantiles:
        for label, a in _lines(ds[metric], x, others):
            v = a.transpose(x, "realization").values.astype(float)
            with warnings.catch_warnings():  # all-NaN points (every run diverged)
                warnings.simplefilter("ignore", RuntimeWarning)
                q = np.nanquantile(v, [0.05, 0.25, 0.5, 0.75, 0.95], axis=1)
            if metric == "max_angle":
                q = np.minimum(q, np.pi)
            ndiv = ""
            if label in div_lines:
                k = int(np.isfinite(div_lines[label].values).sum())
                ndiv = f" ({k} of {v.size} runs diverged)"
            (line,) = ax.plot(xs, q[2], "o-", ms=3, label=(label or metric) + ndiv)
            ax.fill_between(xs, q[0], q[4], color=line.get_color(), alpha=0.12, lw=0)
            ax.fill_between(xs, q[1], q[3], color=line.get_color(), alpha=0.28, lw=0)
            medians.append(q[2])
    if not quantiles:
        m, h = mean_ci(ds, metric)
        for (label, y), (_, e) in zip(_lines(m, x, others), _lines(h, x, others), strict=True):
            yv, ev = y.transpose(x).values, e.transpose(x).values
            (line,) = ax.plot(xs, yv, "o-", ms=3, label=label or metric)
            ax.fill_between(xs, yv - ev, yv + ev, color=line.get_color(), alpha=0.2)
        title = f"mean over {n} realisations, 95 % confidence band"
    else:
        med = np.concatenate(medians)
        med = med[np.isfinite(med) & (med > 0)]
        if med.size and med.max() / med.min() > 10:
            ax.set_yscale("log")
        else:
            ax.set_ylim(bottom=0.0)
        if metric == "max_angle":
            ax.axhline(np.pi / 2, color="k", lw=0.7, ls="-.", label="|theta| = pi/2: fallen")
            ax.set_ylim(top=np.pi)
        ax.fill_between([], [], [], color="grey", alpha=0.28, label="central 50 %")
        ax.fill_between([], [], [], color="grey", alpha=0.12, label="central 90 %")
        title = f"median over {n} realisations, central 50 % and 90 % bands"
    if (
        np.issubdtype(np.asarray(xs).dtype, np.number)
        and np.all(xs > 0)
        and xs.max() / xs.min() > 20
    ):
        ax.set_xscale("log")
    ax.set_xlabel(LABELS.get(x, x))
    ax.set_ylabel(LABELS.get(metric, metric))
    what = LABELS.get(metric, metric).split(" (")[0]
    ax.set_title(f"{what[0].upper()}{what[1:]}\n{title}", fontsize=9)
    ax.legend(fontsize=7)
    fig.savefig(path, dpi=110)
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
    path.write_text("\n".join(lines) + "\n")
    return path
