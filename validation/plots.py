"""Figures (matplotlib, Agg backend): drawing only, no computation."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np


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
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path
