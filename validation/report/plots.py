"""Figures (matplotlib, Agg backend): drawing only, no computation."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from cipcore.atomic import write_with
from cipcore.models import MODEL_NAMES, get_model


def plot_stability_region(
    betas: np.ndarray, taus: np.ndarray, abscissa: np.ndarray, model: str, path: Path
) -> Path:
    """Noise-free stability region in the (beta, tau) plane: spectral abscissa < 0."""
    fig, ax = plt.subplots(figsize=(6, 4.2), constrained_layout=True)
    lim = np.nanmax(np.abs(abscissa))
    pcm = ax.pcolormesh(betas, taus, abscissa, cmap="RdBu_r", vmin=-lim, vmax=lim, shading="auto")
    ax.contour(betas, taus, abscissa, levels=[0.0], colors="k", linewidths=1.5)
    fig.colorbar(pcm, ax=ax, label="max Re s (1/s)")
    ax.set_xlabel(r"gain $\beta$ (1/s$^2$)")
    ax.set_ylabel(r"delay $\tau$ (s)")
    ax.set_title(f"{model} model, $\\nu=0$: stable where max Re s < 0 (black line)")
    write_with(path, lambda tmp: fig.savefig(tmp, dpi=120, format=Path(path).suffix[1:]))
    plt.close(fig)
    return path


def _save(fig, path: Path) -> Path:
    write_with(path, lambda tmp: fig.savefig(tmp, dpi=110, format=Path(path).suffix[1:]))
    plt.close(fig)
    return path


def _finish(
    fig, ax, path: Path, labels: tuple[str, str], title: str, title_size: float = 10
) -> Path:
    """Label the axes ``ax`` (x, y), title them, draw their legend and save ``fig``."""
    ax.set_xlabel(labels[0])
    ax.set_ylabel(labels[1])
    ax.set_title(title, fontsize=title_size)
    ax.legend(fontsize=8)
    return _save(fig, path)


#: the line marking the paper's delay tau = 0.1 s on the STCC figures
DELAY_LINE = {"color": "k", "lw": 0.6, "ls": ":", "label": r"delay $\tau$ = 0.1 s"}


def fig_lle(curve, points, bstar, path: Path, engine: str = "MuJoCo") -> Path:
    """Fig. 3: lambda1 vs beta, reduced curve with 95 % band, the engine's points (labelled
    ``engine``, its family: :attr:`cipcore.engine.Capabilities.family`), beta*."""
    fig, ax = plt.subplots(figsize=(6.4, 4.2), constrained_layout=True)
    colours = {"single": "C0", "coupled": "C3"}
    for model, arr in curve.items():
        b, lam, lo, hi = arr.T
        ax.plot(b, lam, "-", color=colours[model], label=f"reduced, {model}")
        ax.fill_between(b, lo, hi, color=colours[model], alpha=0.2,
                        label=f"reduced, {model}: 95 % CI")  # fmt: skip
        if model in bstar:
            ax.axvline(bstar[model].beta_star, color=colours[model], ls=":", lw=1,
                       label=rf"$\beta^*$ {model} = {bstar[model].beta_star:.4g}")  # fmt: skip
    gone = []  # the engine's runs with no finite exponent (its state went non-finite)
    for row in points:
        f = row["full"]
        lo, hi = f["ci95"]
        if lo is None or hi is None or not np.isfinite(f["lambda1"]):
            gone.append(f"{row['model']} {row['beta']:g}")
            continue
        ax.errorbar(row["beta"], f["lambda1"], yerr=[[f["lambda1"] - lo], [hi - f["lambda1"]]],
                    fmt="s", mfc="none", color=colours[row["model"]], capsize=3)  # fmt: skip
    ax.plot([], [], "ks", mfc="none", label=f"{engine} (95% CI)")
    if gone:
        ax.plot([], [], " ", label="no finite engine estimate (not drawn): " + ", ".join(gone))
    ax.axhline(5e-4, color="k", lw=0.8, ls="--", label=r"$\lambda_1 = 5\times10^{-4}$")
    ax.set_xlabel(r"feedback gain $\beta$ (1/s$^2$)")
    ax.set_ylabel(r"$\lambda_1$ (1/s)")
    ax.legend(fontsize=8)
    ax.set_title(r"Largest Lyapunov exponent $\lambda_1$ against the gain $\beta$")
    return _save(fig, path)


def fig_be(series, path: Path, engine: str = "MuJoCo") -> Path:
    """Fig. 4: balancing error of one realisation, single and coupled, both engines."""
    fig, axes = plt.subplots(2, 1, figsize=(7, 4.6), sharex=True, constrained_layout=True)
    for ax, model in zip(axes, MODEL_NAMES, strict=True):
        full, red = series[model]["full"], series[model]["reduced"]
        ax.plot(red.time, red["balancing_error"][0, :, 0], lw=0.8, label="reduced")
        ax.plot(full.time, full["balancing_error"][0, :, 0], lw=0.8, ls="--", label=engine)
        ax.set_ylabel(
            r"$\Delta x$ (m)" if get_model(model).n_controllers == 1 else r"$\Delta q_1$ (m)"
        )
        ax.set_title(f"{model}, beta = {red.attrs['beta']}", fontsize=9)
        ax.legend(fontsize=8)
    axes[-1].set_xlabel("t (s)")
    fig.suptitle(f"Balancing error of realisation 0, reduced model and {engine} (same noise)",
                 fontsize=10)  # fmt: skip
    return _save(fig, path)


def fig_pwsp(series, peaks, path: Path, engine: str = "MuJoCo") -> Path:
    """Fig. 5: power spectra of the balancing errors with the two-power-law fits."""
    fig, axes = plt.subplots(1, 2, figsize=(9, 4.4), constrained_layout=True)
    for ax, model in zip(axes, MODEL_NAMES, strict=True):
        d = peaks[f"pwsp_{model}"]
        ax.loglog(d["f"], d["S"], lw=0.8, label="reduced (long run), mean")
        if "S_quantiles" in d:  # the realisations' spread: median, central 50 % and 90 %
            q = d["S_quantiles"]
            ax.fill_between(d["f"], q[0], q[4], color="grey", alpha=0.15, lw=0,
                            label="long run: central 90 %")  # fmt: skip
            ax.fill_between(d["f"], q[1], q[3], color="grey", alpha=0.3, lw=0,
                            label="long run: central 50 %")  # fmt: skip
            ax.loglog(d["f"], q[2], color="k", lw=0.6, label="long run: median")
        for eng, key in (("reduced", "metrics_reduced"), (engine, "metrics_full")):
            f, s = series[model][key].spectrum
            ax.loglog(f, s.mean(axis=0) / s.mean() * d["S"].mean(), lw=0.8, alpha=0.7,
                      label=f"{eng}, small amplitude (scaled)")  # fmt: skip
        fit = d["fit"]
        fc = fit.crossover
        s_c = np.interp(fc, d["f"], d["S"])
        for slope, rng in ((fit.slope_low, (fit.fmin, fc)), (fit.slope_high, (fc, fit.fmax))):
            ff = np.geomspace(*rng, 10)
            ax.loglog(ff, s_c * (ff / fc) ** slope, "k--", lw=1,
                      label="two-power-law fit" if slope == fit.slope_low else None)  # fmt: skip
        ax.set_title(f"{model}: slopes {fit.slope_low:.2f}, {fit.slope_high:.2f}", fontsize=9)
        ax.set_xlabel("f (Hz)")
    axes[0].set_ylabel(r"$S$ (m$^2$/Hz)")
    # one legend for both panels (the same line styles), below them
    fig.legend(*axes[0].get_legend_handles_labels(), loc="outside lower center", ncol=4,
               fontsize=7)  # fmt: skip
    fig.suptitle("Power spectra of the balancing error: mean over realisations (fitted) and "
                 "the realisations' spread", fontsize=10)  # fmt: skip
    return _save(fig, path)


#: central quantile bands drawn for heavy-tailed quantities: (lower, upper) quantiles
QUANTILE_BANDS = ((0.05, 0.95), (0.25, 0.75))


def fig_rms(rms, path: Path, length: float) -> Path:
    """Fig. 6: RMS of each realisation on a log axis, single vs coupled.

    Per model: the realisations (dots; crosses beyond the pendulum length
    ``length`` = L = g / alpha (m), where the stick has fallen: counted as
    diverged) and the median (solid line).  Beside them, one bar per model:
    the central 50 % (thick) and 90 % (thin) of the realisations, the median
    (black tick) and the geometric mean (diamond).  The paper draws the means
    of the logarithms; the arithmetic mean of a heavy-tailed sample is not
    drawn.
    """
    from matplotlib.lines import Line2D
    from matplotlib.ticker import MaxNLocator

    fig, ax = plt.subplots(figsize=(9.0, 4.2), constrained_layout=True)
    handles = []
    n_max = max(np.asarray(rms[m]["rms"]).size for m in ("single", "coupled"))
    for k, (model, c) in enumerate((("single", "C0"), ("coupled", "C3"))):
        r = np.asarray(rms[model]["rms"], dtype=float)
        idx = np.arange(r.size)
        fallen = ~(r <= length)  # NaN / inf count as diverged too
        ax.semilogy(idx[~fallen], r[~fallen], ".", color=c, ms=3)
        ax.semilogy(idx[fallen & np.isfinite(r)], r[fallen & np.isfinite(r)], "x", color=c, ms=4)
        fin = r[np.isfinite(r) & (r > 0)]
        med = np.median(fin)
        ax.hlines(med, -0.5, n_max - 0.5, color=c, lw=1.2)
        xb = n_max - 0.5 + n_max * (0.05 + 0.06 * k)  # the summary bar beside the points
        (lo90, hi90), (lo50, hi50) = (np.quantile(fin, q) for q in QUANTILE_BANDS)
        ax.vlines(xb, lo90, hi90, color=c, lw=2, alpha=0.6)
        ax.vlines(xb, lo50, hi50, color=c, lw=8)
        ax.plot([xb], [med], "_", color="k", ms=14, mew=2)
        ax.plot([xb], [np.exp(np.mean(np.log(fin)))], "D", color="k", mfc="white", ms=5)
        label = f"{model}: {int(fallen.sum())} of {r.size} beyond L (diverged, x)"
        handles.append(Line2D([], [], color=c, marker=".", ls="", label=label))
    ax.axhline(length, color="k", lw=0.8, ls="-.")
    style = [Line2D([], [], color="grey", lw=1.2, label="median (line; tick on the bar)"),
             Line2D([], [], color="k", marker="D", mfc="white", ls="", label="geometric mean"),
             Line2D([], [], color="grey", lw=8, label="central 50 % of realisations"),
             Line2D([], [], color="grey", lw=2, alpha=0.6, label="central 90 % of realisations"),
             Line2D([], [], color="k", lw=0.8, ls="-.",
                    label=f"L = g/alpha = {length:.3g} m (stick fallen above)")]  # fmt: skip
    ax.legend(handles=handles + style, fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    ax.set_xlim(-0.5, n_max - 0.5 + n_max * 0.16)
    ax.axvline(n_max - 0.5 + n_max * 0.02, color="grey", lw=0.5)
    ticks = MaxNLocator(nbins=8, integer=True).tick_values(0, n_max - 1)
    ax.set_xticks([t for t in ticks if 0 <= t <= n_max - 1])  # realisations only, not the bars
    ax.set_xlabel("realisation (bars at the right: single, coupled)")
    ax.set_ylabel("RMS of balancing error (m, log axis)")
    ax.set_title("RMS of the balancing error, one point per realisation (reduced model)",
                 fontsize=10)  # fmt: skip
    return _save(fig, path)


def fig_velo(rms, path: Path) -> Path:
    """Fig. 7: ratio of velocity-error densities p(dq1/dt) / p(dx/dt)."""
    centres, ratio = rms["velo"]
    fig, ax = plt.subplots(figsize=(6.4, 3.8), constrained_layout=True)
    ax.plot(centres, ratio, "o-", ms=3, label=r"$p(\dot{\Delta q}_1) / p(\dot{\Delta x})$, reduced")
    ax.axhline(1.0, color="k", lw=0.6, label="ratio 1: coupling changes nothing")
    ax.plot([0.0], [2.0], "k*", ms=9, ls="", label="paper: about 2 near 0 (text)")
    labels = ("velocity error (m/s)", r"$p(\dot{\Delta q}_1) / p(\dot{\Delta x})$")
    title = "Velocity-error densities, coupled over single (reduced model)"
    return _finish(fig, ax, path, labels, title)


def fig_scc(peaks, series, path: Path) -> Path:
    """Fig. 8: STCC R(q_T', q_Mi') of the coupled model at t = 36 (Dt = 5)."""
    d = peaks["scc_coupled"]
    fig, ax = plt.subplots(figsize=(6.4, 3.8), constrained_layout=True)
    ax.plot(d["lags"], d["R"], label=r"$R(\dot q_T, \dot q_{M1})$")
    ax.plot(d["lags"], d["R2"], label=r"$R(\dot q_T, \dot q_{M2})$")
    ax.axvline(0.1, **DELAY_LINE)
    title = f"STCC, coupled reduced model, t = {d['t']:.1f} s, Dt = 5 s"
    return _finish(fig, ax, path, (r"lag $\tau$ (s)", "R"), title, title_size=9)


def fig_sccpeak(peaks, path: Path) -> Path:
    """Fig. 9: first peak points tau_hat(t) for x, q1, q2 (one realisation)."""
    fig, axes = plt.subplots(3, 1, figsize=(7, 6.0), sharex=True, constrained_layout=True)
    rows = [("single", 0, r"$\hat\tau_{\dot x}$", r"single: $R(\dot x_T, \dot x_M)$"),
            ("coupled", 0, r"$\hat\tau_{\dot q_1}$", r"coupled: $R(\dot q_T, \dot q_{M1})$"),
            ("coupled", 1, r"$\hat\tau_{\dot q_2}$",
             r"coupled: $R(\dot q_T, \dot q_{M2})$")]  # fmt: skip
    for ax, (model, i, lab, title) in zip(axes, rows, strict=True):
        d = peaks[f"peaks_{model}"]
        th = d["tau_hat"][0, :, i]
        ax.plot(d["t"], th, ".", ms=2, label="first dominant peak " + lab)
        ax.axhline(0.1, **DELAY_LINE)
        n = int(np.isfinite(th).sum())
        ax.set_title(f"{title}: {n} of {th.size} windows with a peak", fontsize=9)
        ax.set_ylabel(lab + " (s)")
        ax.set_ylim(0.0, float(d["edges"][-1]))
        ax.legend(fontsize=7, loc="upper right")
    axes[-1].set_xlabel("t (s)")
    fig.suptitle("First peak points of the STCC, one realisation (reduced model)", fontsize=10)
    return _save(fig, path)


def fig_sccpeak_pdf(peaks, series, path: Path, engine: str = "MuJoCo") -> Path:
    """Fig. 10: densities of tau_hat, single vs coupled (reduced and the engine)."""
    fig, ax = plt.subplots(figsize=(6.4, 3.8), constrained_layout=True)
    for model, c, mk in (("single", "C0", "^"), ("coupled", "C3", "s")):
        d = peaks[f"peaks_{model}"]
        e = d["edges"]
        ax.plot(0.5 * (e[1:] + e[:-1]), d["density"], mk + "-", color=c, ms=4,
                label=f"reduced, {model}")  # fmt: skip
        th = series[model]["metrics_full"].tau_hat.ravel()
        th = th[np.isfinite(th)]
        if th.size:
            h, _ = np.histogram(th, bins=e, density=True)
            ax.plot(0.5 * (e[1:] + e[:-1]), h, mk + "--", color=c, ms=3, mfc="none",
                    label=f"{engine}, {model} (small amplitude)")  # fmt: skip
    ax.axvline(0.1, **DELAY_LINE)
    title = r"Densities of the first peak point $\hat\tau$"
    return _finish(fig, ax, path, (r"$\hat\tau$ (s)", "density (1/s)"), title)


def fig_scan(scan, path: Path, engine: str = "MuJoCo") -> Path:
    """Amplitude scan: relative L2 distance full vs reduced against the largest angle."""
    fig, ax = plt.subplots(figsize=(6.4, 3.8), constrained_layout=True)
    for model, c in (("single", "C0"), ("coupled", "C3")):
        rows = [r for r in scan if r["model"] == model]
        ax.loglog([r["max_abs_angle"] for r in rows], [r["relative_l2"] for r in rows], "o-",
                  color=c, label=model)  # fmt: skip
    ax.axhline(0.01, color="k", lw=0.6, ls="--", label="1 %")
    from cip.model import small_angle_limit

    ax.axvline(small_angle_limit(), color="grey", lw=0.6, ls=":", label="small-angle limit")
    ax.axvline(np.pi / 2, color="k", lw=0.6, ls="-.", label=r"$|\theta| = \pi/2$: fallen")
    labels = (r"largest $|\theta|$ reached (rad)", "relative L2 distance of balancing errors")
    title = f"{engine} against the reduced model by initial amplitude (same noise)"
    return _finish(fig, ax, path, labels, title)


def paper_figures(out_dir: Path, data: Mapping[str, Any], *, only=None) -> list[Path]:
    """Write the figures of the report named in ``only`` (file names; default every one),
    in the report's order (:data:`validation.report.figures.PAPER_FIGURES`, which also
    names the data each needs); returns their paths.

    ``data`` holds the stages' results by name: ``curve`` (lambda1 over the gains),
    ``lyapunov_points``, ``bstar``, ``series``, ``rms``, ``peaks``, ``scan``; a figure
    whose data is missing is not asked for.  ``engine`` (optional) labels the engine's
    data: its family (:attr:`cipcore.engine.Capabilities.family`, default "MuJoCo").
    """
    engine = data.get("engine") or "MuJoCo"
    curve, lyapunov_points, bstar = (
        data.get("curve"),
        data.get("lyapunov_points"),
        data.get("bstar"),
    )
    series, rms, peaks, scan = (
        data.get("series"),
        data.get("rms"),
        data.get("peaks"),
        data.get("scan"),
    )
    from cipcore.params import BalanceParams
    from validation.checks.divergence import pendulum_length
    from validation.profiles import PAPER_BETA

    length = pendulum_length(BalanceParams(beta=PAPER_BETA["single"]))  # L = g / alpha
    draw = {
        "fig_lLe.png": lambda p: fig_lle(curve, lyapunov_points, bstar, p, engine),
        "fig_Be.png": lambda p: fig_be(series, p, engine),
        "fig_pwsp.png": lambda p: fig_pwsp(series, peaks, p, engine),
        "fig_rms.png": lambda p: fig_rms(rms, p, length),
        "fig_velo.png": lambda p: fig_velo(rms, p),
        "fig_scc.png": lambda p: fig_scc(peaks, series, p),
        "fig_sccpeak.png": lambda p: fig_sccpeak(peaks, p),
        "fig_sccpeak_pdf.png": lambda p: fig_sccpeak_pdf(peaks, series, p, engine),
        "fig_amplitude_scan.png": lambda p: fig_scan(scan, p, engine),
    }
    unknown = set(only or ()) - set(draw)
    if unknown:
        raise ValueError(f"no paper figure named {sorted(unknown)}; figures: {list(draw)}")
    return [draw[name](out_dir / name) for name in draw if only is None or name in only]
