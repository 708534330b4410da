"""Verdicts (pass / fail / inconclusive) whose tolerances come from the statistics.

Two rules, both stated next to every verdict in the report:

* **CI overlap** for two independent estimates with 95 % confidence
  intervals (lambda1 of two models): pass when the difference of the means is
  within the larger half-width (each mean lies inside the other's interval,
  up to the larger interval), fail when the intervals are disjoint,
  inconclusive in between.

* **Paired equivalence** for per-realisation values of the two models driven
  by the *same* noise: the margin is the statistical resolution of the
  metric itself, the 95 % half-width of its mean over realisations
  (t_{0.975, n-1} s / sqrt(n)).  With d the paired differences and [lo, hi]
  their 95 % t-interval: pass when [lo, hi] lies inside +-margin (the models
  differ by less than the metric can resolve), fail when it lies wholly
  outside, inconclusive otherwise.  This is a two one-sided tests (TOST)
  equivalence test with a data-derived margin.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

from reduced.lyapunov import ci95_half_width

PASS, FAIL, INCONCLUSIVE = "pass", "fail", "inconclusive"


@dataclass
class Check:
    """One verdict of the harness: name, status, numbers and the tolerance used."""

    name: str
    status: str
    values: dict[str, Any] = field(default_factory=dict)
    tolerance: str = ""
    details: str = ""

    def as_dict(self) -> dict:
        return asdict(self)


def t_half_width(x: np.ndarray) -> float:
    """Student-t 95 % half-width of the finite values of ``x`` (NaN for fewer than 2)."""
    x = np.asarray(x, dtype=float)
    return ci95_half_width(x[np.isfinite(x)])


def ci_overlap(m1: float, ci1, m2: float, ci2) -> tuple[str, dict]:
    """Verdict for two means with 95 % CIs (rule in the module docstring)."""
    h1 = (ci1[1] - ci1[0]) / 2
    h2 = (ci2[1] - ci2[0]) / 2
    diff = abs(m1 - m2)
    if not all(np.isfinite([m1, m2, h1, h2])):
        status = INCONCLUSIVE
    elif diff <= max(h1, h2):
        status = PASS
    elif diff > h1 + h2:
        status = FAIL
    else:
        status = INCONCLUSIVE
    return status, {"difference": m1 - m2, "half_width_1": h1, "half_width_2": h2}


def paired_equivalence(full: np.ndarray, reduced: np.ndarray) -> tuple[str, dict]:
    """Verdict for per-realisation values under the same noise (module docstring).

    Returns the status and the numbers: mean of each, the paired difference's
    mean and 95 % interval, and the margin.
    """
    a = np.asarray(full, dtype=float).ravel()
    b = np.asarray(reduced, dtype=float).ravel()
    ok = np.isfinite(a) & np.isfinite(b)
    a, b = a[ok], b[ok]
    if a.size < 2:
        return INCONCLUSIVE, {"n": int(a.size)}
    d = a - b
    hw = t_half_width(d)
    margin = t_half_width(b)
    lo, hi = d.mean() - hw, d.mean() + hw
    if lo >= -margin and hi <= margin:
        status = PASS
    elif lo > margin or hi < -margin:
        status = FAIL
    else:
        status = INCONCLUSIVE
    n = a.size
    return status, {
        "n": int(n),
        "full": {"value": float(a.mean()), "se": float(a.std(ddof=1) / np.sqrt(n))},
        "reduced": {"value": float(b.mean()), "se": float(b.std(ddof=1) / np.sqrt(n))},
        "difference_mean": float(d.mean()),
        "difference_ci95": [float(lo), float(hi)],
        "margin": float(margin),
    }


def se_agreement(v1: float, se1: float, v2: float, se2: float) -> tuple[str, dict]:
    """Two estimates with standard errors: pass within 2 sigma, fail beyond 3 sigma."""
    s = float(np.hypot(se1, se2))
    z = abs(v1 - v2) / s if s > 0 else float("inf")
    if not np.isfinite(z):
        status = INCONCLUSIVE if not (np.isfinite(v1) and np.isfinite(v2)) else FAIL
    elif z <= 2:
        status = PASS
    elif z > 3:
        status = FAIL
    else:
        status = INCONCLUSIVE
    return status, {"difference": v1 - v2, "sigma": s, "z": z}


def worst(statuses: list[str]) -> str:
    """fail beats inconclusive beats pass."""
    if FAIL in statuses:
        return FAIL
    if INCONCLUSIVE in statuses:
        return INCONCLUSIVE
    return PASS


# ------------------------------------------------- heavy-tailed samples
def geometric_mean(x: np.ndarray, axis: int = -1) -> np.ndarray:
    """exp(mean(log x)) of positive values (paper Fig. rms plots log RMS)."""
    return np.exp(np.mean(np.log(np.asarray(x, dtype=float)), axis=axis))


STATISTICS = {"median": lambda a: np.median(a, axis=-1), "geometric_mean": geometric_mean,
              "mean": lambda a: np.mean(a, axis=-1)}  # fmt: skip


def bootstrap_ci(
    x: np.ndarray, statistic: str, n_bootstrap: int = 2000, seed: int = 0
) -> tuple[float, float, float]:
    """Estimate and 95 % percentile-bootstrap interval of a statistic of realisations ``x``.

    ``statistic``: "median", "geometric_mean" or "mean"; resampling is over
    realisations with ``np.random.default_rng(seed)``.
    """
    x = np.asarray(x, dtype=float).ravel()
    f = STATISTICS[statistic]
    rng = np.random.default_rng(seed)
    boot = f(x[rng.integers(0, x.size, (n_bootstrap, x.size))])
    lo, hi = np.percentile(boot, [2.5, 97.5])
    return float(f(x)), float(lo), float(hi)


def bootstrap_ratio_ci(
    a: np.ndarray, b: np.ndarray, statistic: str, n_bootstrap: int = 2000, seed: int = 0
) -> tuple[float, float, float]:
    """stat(a) / stat(b) with a 95 % percentile bootstrap, a and b resampled independently."""
    a = np.asarray(a, dtype=float).ravel()
    b = np.asarray(b, dtype=float).ravel()
    f = STATISTICS[statistic]
    rng = np.random.default_rng(seed)
    ia = rng.integers(0, a.size, (n_bootstrap, a.size))
    ib = rng.integers(0, b.size, (n_bootstrap, b.size))
    boot = f(a[ia]) / f(b[ib])
    lo, hi = np.percentile(boot, [2.5, 97.5])
    return float(f(a) / f(b)), float(lo), float(hi)


def heavy_tailed_summary(
    x: np.ndarray, thresholds: tuple[float, ...] = (), n_bootstrap: int = 2000, seed: int = 0
) -> dict:
    """Statistics of per-realisation values (e.g. RMS) that stay meaningful for heavy tails.

    Median and geometric mean with 95 % bootstrap intervals; the fraction of
    realisations above each threshold; and the mean with its interval and the
    share of the sum carried by the largest realisation, which states how
    unstable the mean is (near 1: one draw sets it, and another seed moves it
    by orders of magnitude).
    """
    x = np.asarray(x, dtype=float).ravel()
    x = x[np.isfinite(x)]
    out: dict[str, Any] = {"n": int(x.size)}
    for k, stat in enumerate(("median", "geometric_mean", "mean")):
        v, lo, hi = bootstrap_ci(x, stat, n_bootstrap, seed + k)
        out[stat] = {"value": v, "ci95": [lo, hi]}
    out["mean"]["largest_share"] = float(x.max() / x.sum()) if x.sum() > 0 else float("nan")
    out["log10_spread"] = float(np.log10(x.max() / x.min())) if x.min() > 0 else float("inf")
    out["fraction_above"] = {f"{t:g}": float(np.mean(x > t)) for t in thresholds}
    return out
