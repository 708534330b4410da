"""Figures (matplotlib, Agg backend): drawing only, no computation."""

from __future__ import annotations

from pathlib import Path

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


def fig_lle(curve, points, bstar, path: Path) -> Path:
    """Fig. lLe: lambda1 vs beta, reduced curve with 95 % band, MuJoCo points, beta*."""
    fig, ax = plt.subplots(figsize=(6.4, 4.2), constrained_layout=True)
    colours = {"single": "C0", "coupled": "C3"}
    for model, arr in curve.items():
        b, lam, lo, hi = arr.T
        ax.plot(b, lam, "-", color=colours[model], label=f"reduced, {model}")
        ax.fill_between(b, lo, hi, color=colours[model], alpha=0.2)
        if model in bstar:
            ax.axvline(bstar[model].beta_star, color=colours[model], ls=":", lw=1)
    for row in points:
        f = row["full"]
        ax.errorbar(row["beta"], f["lambda1"], yerr=[[f["lambda1"] - f["ci95"][0]],
                    [f["ci95"][1] - f["lambda1"]]], fmt="s", mfc="none",
                    color=colours[row["model"]], capsize=3)  # fmt: skip
    ax.plot([], [], "ks", mfc="none", label="MuJoCo (95% CI)")
    ax.axhline(5e-4, color="k", lw=0.8, ls="--", label=r"$\lambda_1 = 5\times10^{-4}$")
    ax.set_xlabel(r"feedback gain $\beta$ (1/s$^2$)")
    ax.set_ylabel(r"$\lambda_1$ (1/s)")
    ax.legend(fontsize=8)
    ax.set_title("Largest Lyapunov exponent (dotted: beta*)")
    return _save(fig, path)


def fig_be(series, path: Path) -> Path:
    """Fig. Be: balancing error of one realisation, single and coupled, both engines."""
    fig, axes = plt.subplots(2, 1, figsize=(7, 4.6), sharex=True, constrained_layout=True)
    for ax, model in zip(axes, MODEL_NAMES, strict=True):
        full, red = series[model]["full"], series[model]["reduced"]
        ax.plot(red.time, red["balancing_error"][0, :, 0], lw=0.8, label="reduced")
        ax.plot(full.time, full["balancing_error"][0, :, 0], lw=0.8, ls="--", label="MuJoCo")
        ax.set_ylabel(
            r"$\Delta x$ (m)" if get_model(model).n_controllers == 1 else r"$\Delta q_1$ (m)"
        )
        ax.set_title(f"{model}, beta = {red.attrs['beta']}", fontsize=9)
        ax.legend(fontsize=8)
    axes[-1].set_xlabel("t (s)")
    return _save(fig, path)


def fig_pwsp(series, peaks, path: Path) -> Path:
    """Fig. pwsp: power spectra of the balancing errors with the two-power-law fits."""
    fig, axes = plt.subplots(1, 2, figsize=(9, 3.8), constrained_layout=True)
    for ax, model in zip(axes, MODEL_NAMES, strict=True):
        d = peaks[f"pwsp_{model}"]
        ax.loglog(d["f"], d["S"], lw=0.8, label="reduced (long run)")
        for eng, key in (("reduced", "metrics_reduced"), ("MuJoCo", "metrics_full")):
            f, s = series[model][key].spectrum
            ax.loglog(f, s.mean(axis=0) / s.mean() * d["S"].mean(), lw=0.8, alpha=0.7,
                      label=f"{eng}, small amplitude (scaled)")  # fmt: skip
        fit = d["fit"]
        fc = fit.crossover
        s_c = np.interp(fc, d["f"], d["S"])
        for slope, rng in ((fit.slope_low, (fit.fmin, fc)), (fit.slope_high, (fc, fit.fmax))):
            ff = np.geomspace(*rng, 10)
            ax.loglog(ff, s_c * (ff / fc) ** slope, "k--", lw=1)
        ax.set_title(f"{model}: slopes {fit.slope_low:.2f}, {fit.slope_high:.2f}", fontsize=9)
        ax.set_xlabel("f (Hz)")
        ax.legend(fontsize=7)
    axes[0].set_ylabel(r"$S$ (m$^2$/Hz)")
    return _save(fig, path)


def fig_rms(rms, path: Path) -> Path:
    """Fig. rms: log RMS of each realisation, single vs coupled; solid: median, dashed:
    geometric mean (the paper draws the means, which one realisation can set)."""
    fig, ax = plt.subplots(figsize=(6.4, 3.8), constrained_layout=True)
    for k, (model, c) in enumerate((("single", "C0"), ("coupled", "C3"))):
        r = rms[model]["rms"]
        ax.semilogy(np.arange(r.size), r, ".", color=c, ms=3, label=model)
        # the mean of a heavy-tailed sample is unstable: show the median and geometric mean
        ax.axhline(np.median(r), color=c, lw=1)
        ax.axhline(np.exp(np.mean(np.log(r))), color=c, lw=1, ls="--")
        del k
    ax.set_xlabel("realisation")
    ax.set_ylabel("RMS of balancing error (m)")
    ax.legend(fontsize=8)
    return _save(fig, path)


def fig_velo(rms, path: Path) -> Path:
    """Fig. velo: ratio of velocity-error densities p(dq1/dt) / p(dx/dt)."""
    centres, ratio = rms["velo"]
    fig, ax = plt.subplots(figsize=(6.4, 3.8), constrained_layout=True)
    ax.plot(centres, ratio, "o-", ms=3)
    ax.axhline(1.0, color="k", lw=0.6)
    ax.set_xlabel("velocity error (m/s)")
    ax.set_ylabel(r"$p(\dot{\Delta q}_1) / p(\dot{\Delta x})$")
    return _save(fig, path)


def fig_scc(peaks, series, path: Path) -> Path:
    """Fig. scc: STCC R(q_T', q_Mi') of the coupled model at t = 36 (Dt = 5)."""
    d = peaks["scc_coupled"]
    fig, ax = plt.subplots(figsize=(6.4, 3.8), constrained_layout=True)
    ax.plot(d["lags"], d["R"], label=r"$R(\dot q_T, \dot q_{M1})$")
    ax.plot(d["lags"], d["R2"], label=r"$R(\dot q_T, \dot q_{M2})$")
    ax.axvline(0.1, color="k", lw=0.6, ls=":")
    ax.set_xlabel(r"lag $\tau$ (s)")
    ax.set_ylabel("R")
    ax.set_title(f"coupled reduced model, t = {d['t']:.1f} s, Dt = 5 s", fontsize=9)
    ax.legend(fontsize=8)
    return _save(fig, path)


def fig_sccpeak(peaks, path: Path) -> Path:
    """Fig. sccpeak: first peak points tau_hat(t) for x, q1, q2 (one realisation)."""
    fig, axes = plt.subplots(3, 1, figsize=(7, 5.4), sharex=True, constrained_layout=True)
    rows = [("single", 0, r"$\hat\tau_{\dot x}$"), ("coupled", 0, r"$\hat\tau_{\dot q_1}$"),
            ("coupled", 1, r"$\hat\tau_{\dot q_2}$")]  # fmt: skip
    for ax, (model, i, lab) in zip(axes, rows, strict=True):
        d = peaks[f"peaks_{model}"]
        ax.plot(d["t"], d["tau_hat"][0, :, i], ".", ms=2)
        ax.axhline(0.1, color="k", lw=0.6, ls=":")
        ax.set_ylabel(lab + " (s)")
    axes[-1].set_xlabel("t (s)")
    return _save(fig, path)


def fig_sccpeak_pdf(peaks, series, path: Path) -> Path:
    """Fig. sccpeak:pdf: densities of tau_hat, single vs coupled (reduced and MuJoCo)."""
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
                    label=f"MuJoCo, {model} (small amplitude)")  # fmt: skip
    ax.set_xlabel(r"$\hat\tau$ (s)")
    ax.set_ylabel("density (1/s)")
    ax.legend(fontsize=8)
    return _save(fig, path)


def fig_scan(scan, path: Path) -> Path:
    """Amplitude scan: relative L2 distance full vs reduced against the largest angle."""
    fig, ax = plt.subplots(figsize=(6.4, 3.8), constrained_layout=True)
    for model, c in (("single", "C0"), ("coupled", "C3")):
        rows = [r for r in scan if r["model"] == model]
        ax.loglog([r["max_abs_angle"] for r in rows], [r["relative_l2"] for r in rows], "o-",
                  color=c, label=model)  # fmt: skip
    ax.axhline(0.01, color="k", lw=0.6, ls="--", label="1 %")
    from cip.model import small_angle_limit

    ax.axvline(small_angle_limit(), color="grey", lw=0.6, ls=":", label="small-angle limit")
    ax.set_xlabel(r"largest $|\theta|$ reached (rad)")
    ax.set_ylabel("relative L2 distance of balancing errors")
    ax.legend(fontsize=8)
    return _save(fig, path)


def paper_figures(out_dir: Path, *, curve, lyapunov_points, bstar, series, rms, peaks, scan):
    """Write every figure of the report; returns their paths."""
    return [
        fig_lle(curve, lyapunov_points, bstar, out_dir / "fig_lLe.png"),
        fig_be(series, out_dir / "fig_Be.png"),
        fig_pwsp(series, peaks, out_dir / "fig_pwsp.png"),
        fig_rms(rms, out_dir / "fig_rms.png"),
        fig_velo(rms, out_dir / "fig_velo.png"),
        fig_scc(peaks, series, out_dir / "fig_scc.png"),
        fig_sccpeak(peaks, out_dir / "fig_sccpeak.png"),
        fig_sccpeak_pdf(peaks, series, out_dir / "fig_sccpeak_pdf.png"),
        fig_scan(scan, out_dir / "fig_amplitude_scan.png"),
    ]
