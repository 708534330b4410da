"""One Student-t confidence interval for the mean of i.i.d. samples.

Every mean with a 95 % CI in the suite (lambda1 over realisations, sweep
points, per-realisation metrics) comes from here:

    half-width = t_{0.975, n-1} * s / sqrt(n),   s the sample standard deviation.

With fewer than two samples the half-width is NaN; a non-finite sample makes
the mean and CI non-finite (a diverged realisation is never hidden): callers
that want only the finite values say so with ``finite_only=True``.
"""

from __future__ import annotations

import numpy as np


def ci95_half_width(samples: np.ndarray, *, finite_only: bool = False) -> float:
    """Student-t 95 % half-width t_{0.975, n-1} s / sqrt(n) of i.i.d. samples (NaN for n < 2)."""
    x = np.asarray(samples, dtype=float).ravel()
    if finite_only:
        x = x[np.isfinite(x)]
    n = x.size
    if n < 2:
        return float("nan")
    import scipy.stats

    return float(scipy.stats.t.ppf(0.975, n - 1) * x.std(ddof=1) / np.sqrt(n))


def mean_ci95(samples: np.ndarray) -> tuple[float, tuple[float, float]]:
    """Mean and Student-t 95 % confidence interval of i.i.d. samples (NaN CI for n < 2)."""
    x = np.asarray(samples, dtype=float).ravel()
    m = float(x.mean()) if x.size else float("nan")
    half = ci95_half_width(x)
    return m, (m - half, m + half)


def standard_error(samples: np.ndarray) -> float:
    """s / sqrt(n) of the finite values (NaN for n < 2)."""
    x = np.asarray(samples, dtype=float)
    x = x[np.isfinite(x)]
    return float(x.std(ddof=1) / np.sqrt(x.size)) if x.size > 1 else float("nan")
