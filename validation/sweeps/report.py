"""Plots and the Markdown report of a sweep dataset."""

from __future__ import annotations

import json
import textwrap
import warnings
from pathlib import Path

import numpy as np

from cipcore.atomic import write_text, write_with
from cipcore.params import ParameterError
from validation.sweeps.store import is_number
from validation.sweeps.study import Study

#: axis labels of the settings and metrics (kept for callers; plots read the dataset's
#: CF ``long_name`` / ``units``, see :mod:`validation.sweeps.attrs`)
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


def median_ci(ds, name: str, seed: int = 0):
    """Median over realisations and its percentile-bootstrap 95 % interval (NaNs dropped):
    (median, low, high) DataArrays over the other dimensions."""
    import xarray as xr

    from validation.sweeps.paired import summary_ci

    a = ds[name]
    if "realization" not in a.dims:
        return a, a * np.nan, a * np.nan
    a = a.transpose(..., "realization")
    shape = a.shape[:-1]
    est, lo, hi = np.full(shape, np.nan), np.full(shape, np.nan), np.full(shape, np.nan)
    for i, idx in enumerate(np.ndindex(*shape)):
        est[idx], lo[idx], hi[idx] = summary_ci(a.values[idx], "median", seed, i)
    coords = {d: a[d] for d in a.dims[:-1]}
    return tuple(xr.DataArray(v, dims=a.dims[:-1], coords=coords) for v in (est, lo, hi))


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
    log axis where the medians span more than a decade, angles capped at pi
    (the pendulum's largest |theta|); the realisations that diverged
    (``divergence_time`` finite) are counted per line in the legend.  Other
    per-realisation metrics: the median with its bootstrap 95 % band; a
    per-point quantity: its value, with its ``_ci_low`` / ``_ci_high`` band when
    the dataset has one.  Axes carry the variables' ``long_name [units]``.

    The function is long because one figure's layout is said in one place.
    """
    from validation.report.plots import plt
    from validation.sweeps.attrs import label

    if metric not in ds:
        raise ParameterError(
            f"--metric: {metric!r} not in the sweep; has {', '.join(ds.data_vars)}"
        )
    if x not in ds.dims or x == "realization":
        dims = [d for d in ds.dims if d != "realization"]
        raise ParameterError(f"--x: {x!r} is not a swept parameter; swept: {', '.join(dims)}")
    per = "realization" in ds[metric].dims
    quantiles = metric in QUANTILE_METRICS and per
    others = [d for d in ds[metric].dims if d not in (x, "realization")]
    fig, ax = plt.subplots(figsize=(6.4, 4.0), constrained_layout=True)
    xs = ds[x].values
    n = ds.sizes.get("realization", 1)
    if quantiles:
        div = ds["divergence_time"] if "divergence_time" in ds else None
        div_lines = dict(_lines(div, x, others)) if div is not None else {}
        medians = []
        for name, a in _lines(ds[metric], x, others):
            v = a.transpose(x, "realization").values.astype(float)
            with warnings.catch_warnings():  # all-NaN points (every run diverged)
                warnings.simplefilter("ignore", RuntimeWarning)
                q = np.nanquantile(v, [0.05, 0.25, 0.5, 0.75, 0.95], axis=1)
            if metric == "max_angle":
                q = np.minimum(q, np.pi)
            ndiv = ""
            if name in div_lines:
                k = int(np.isfinite(div_lines[name].values).sum())
                ndiv = f" ({k} of {v.size} runs diverged)"
            (line,) = ax.plot(xs, q[2], "o-", ms=3, label=(name or metric) + ndiv)
            ax.fill_between(xs, q[0], q[4], color=line.get_color(), alpha=0.12, lw=0)
            ax.fill_between(xs, q[1], q[3], color=line.get_color(), alpha=0.28, lw=0)
            medians.append(q[2])
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
        what = f"median over {n} realisations, central 50 % and 90 % bands"
    else:
        if per:
            m, lo, hi = median_ci(ds, metric)
            what = f"median over {n} realisations, bootstrap 95 % band"
        elif f"{metric}_ci_low" in ds:
            m, lo, hi = ds[metric], ds[f"{metric}_ci_low"], ds[f"{metric}_ci_high"]
            what = "per grid point, bootstrap 95 % band"
        else:
            m, lo, hi = ds[metric], ds[metric] * np.nan, ds[metric] * np.nan
            what = "per grid point"
        for (name, y), (_, yl), (_, yh) in zip(
            _lines(m, x, others), _lines(lo, x, others), _lines(hi, x, others), strict=True
        ):
            (line,) = ax.plot(xs, y.transpose(x).values, "o-", ms=3, label=name or metric)
            ax.fill_between(xs, yl.transpose(x).values, yh.transpose(x).values,
                            color=line.get_color(), alpha=0.2)  # fmt: skip
    if (
        np.issubdtype(np.asarray(xs).dtype, np.number)
        and np.all(xs > 0)
        and xs.max() / xs.min() > 20
    ):
        ax.set_xscale("log")
    ax.set_xlabel(label(x, dict(ds[x].attrs)))
    ax.set_ylabel(textwrap.fill(label(metric, dict(ds[metric].attrs)), 42), fontsize=9)
    ax.set_title(what, fontsize=8)
    ax.legend(fontsize=7)
    write_with(path, lambda tmp: fig.savefig(tmp, dpi=110, format=Path(path).suffix[1:]))
    plt.close(fig)
    return path


def _ci(v: float, lo: float, hi: float) -> str:
    return f"{v:.3g} [{lo:.3g}, {hi:.3g}]"


def _cells(ds, metric: str, sel: dict, seed: int, index: int) -> list[str]:
    """Report cells of one per-realisation metric at one point: heavy-tail summaries."""
    from validation.sweeps.paired import summary_ci

    v = np.asarray(ds[metric].sel(sel).values, dtype=float)
    if metric == "rms":
        r = 10.0**v
        med = summary_ci(r, "median", seed, index)
        geo = summary_ci(r, "geomean", seed, index)
        fin = r[np.isfinite(r)]
        share = float(fin.max() / fin.sum()) if fin.size and fin.sum() > 0 else float("nan")
        return [_ci(*med), _ci(*geo), f"{fin.mean():.3g} (largest {100 * share:.0f} %)"]
    return [_ci(*summary_ci(v, "median", seed, index))]


def write_sweep_report(study: Study, out_dir: Path) -> Path:
    """DIR/report.md: the settings, one figure per metric against the first swept parameter
    (median and bootstrap 95 % band), the paired comparisons of a ``compare`` study and its
    target gains beta* with their intervals, and a table of heavy-tail summaries.

    The function is long because it writes the report's sections in order.
    """
    import xarray as xr

    from validation.sweeps.attrs import label

    out_dir = Path(out_dir)
    with xr.open_dataset(out_dir / "sweep.nc", engine="scipy") as ds:
        ds = ds.load()
    x = next(iter(study.grid))
    models = " vs ".join(study.compare) if study.compare else study.model
    settings = {k: np.asarray(v).tolist() for k, v in ds.attrs.items()
                if k.startswith(("param_", "stcc_", "gain_"))}  # fmt: skip
    lines = [f"# Sweep {study.name}", "",
             f"{models} model, engine {study.engine}, {study.realizations} realisations x "
             f"{study.duration:g} s per point, seed {study.seed} "
             f"({'common random numbers' if study.common_random_numbers else 'seed per point'}"
             f"{'; the compared models share each point seed' if study.compare else ''}).",
             "", f"Fixed: {json.dumps(study.fixed)}", "",
             f"Settings in force: {json.dumps(settings)}", ""]  # fmt: skip
    if study.gain:
        g = study.gain
        lines += [f"beta per point: beta*, where lambda1 of the reduced model = "
                  f"{g['target_lambda1']:g} 1/s ({g['gains']} gains over the paper gain +- "
                  f"{g['half_width']:g} 1/s^2, {g['realizations']} realisations x "
                  f"{g['duration']:g} s, quadratic fit, bootstrap 95 % interval).", ""]  # fmt: skip
        png = plot_metric(ds, "beta_star", x, out_dir / "sweep_beta_star.png")
        lines += [f"![beta_star]({png.name})", ""]
    if study.compare:
        ref, cmp_ = study.compare
        lines += [f"## {cmp_} vs {ref} (paired by realisation: same seed and stream)", "",
                  "Ratios: compared / reference; differences: compared - reference; "
                  "percentile bootstrap 95 % intervals over paired realisations.", ""]  # fmt: skip
        paired = [v for v in ds.data_vars if ("_ratio_" in v or "_diff_" in v)
                  and not v.endswith(("_ci_low", "_ci_high"))]  # fmt: skip
        for v in paired:
            if v.startswith("rms_ratio"):
                png = plot_metric(ds, v, x, out_dir / f"sweep_{v}.png")
                lines += [f"![{v}]({png.name})", ""]
        gdims = list(study.grid)
        head = gdims + [label(v, dict(ds[v].attrs)) for v in paired]
        lines += ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
        pts = [{k: p[k] for k in gdims} for p in study.points() if p["model"] == ref]
        for point in pts:
            sel = {k: (float(v) if is_number(v) else str(v)) for k, v in point.items()}
            cells = [str(point[k]) for k in gdims]
            for v in paired:
                cells.append(_ci(float(ds[v].sel(sel)), float(ds[f"{v}_ci_low"].sel(sel)),
                                 float(ds[f"{v}_ci_high"].sel(sel))))  # fmt: skip
            lines.append("| " + " | ".join(cells) + " |")
        lines.append("")
    per = [m for m in ds.data_vars if "realization" in ds[m].dims and m != "divergence_time"]
    for metric in per:
        png = plot_metric(ds, metric, x, out_dir / f"sweep_{metric}.png")
        lines += [f"![{metric}]({png.name})", ""]
    lines += ["## Per point", "",
              "Median and geometric mean over realisations with percentile-bootstrap 95 % "
              "intervals (the RMS of the balancing error is heavy-tailed: its mean is carried "
              "by the largest realisations, shown as that realisation's share of the sum, and "
              "is not a stable summary).  tau_hat: median first dominant STCC peak over the "
              "windows that have one, read beside tau_hat_fraction (the fraction of windows "
              "with a peak); tau_hat_avg: lag of the maximum of the window-averaged STCC.  "
              "Slopes: fit of the mean spectrum +- 1.96 bootstrap SE.", ""]  # fmt: skip
    dims = list(study.axes())
    head = list(dims)
    for m in per:
        if m == "rms":
            head += ["median RMS (m) [95%]", "geometric-mean RMS (m) [95%]",
                     "mean RMS (m), unstable"]  # fmt: skip
        else:
            lab = label(m, dict(ds[m].attrs))
            head.append(f"{lab if lab.startswith('median') else 'median ' + lab} [95%]")
    slopes = [k for k in ("slope_low", "slope_high") if k in ds]
    head += [f"{k} [95%]" for k in slopes]
    if "divergence_time" in ds:
        head.append("diverged (realisations)")
    lines += ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for i, point in enumerate(study.points()):
        sel = {k: (float(v) if is_number(v) else str(v)) for k, v in point.items()}
        cells = [str(point[k]) for k in dims]
        for m in per:
            cells += _cells(ds, m, sel, study.seed, i)
        for k in slopes:
            v, se = float(ds[k].sel(sel)), float(ds[f"{k}_se"].sel(sel))
            cells.append(_ci(v, v - 1.96 * se, v + 1.96 * se))
        if "divergence_time" in ds:
            t = ds["divergence_time"].sel(sel).values
            cells.append(str(int(np.isfinite(t).sum())))
        lines.append("| " + " | ".join(cells) + " |")
    path = out_dir / "report.md"
    write_text(path, "\n".join(lines) + "\n")
    return path
