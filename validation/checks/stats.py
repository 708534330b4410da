"""Verdicts (pass / fail / inconclusive) whose tolerances come from the statistics.

Two rules, both stated next to every verdict in the report:

* **CI overlap** for two independent estimates with 95 % confidence
  intervals (lambda1 of two models): pass when the difference of the means is
  within the larger half-width (each mean lies inside the other's interval,
  up to the larger interval), fail when the intervals are disjoint,
  inconclusive in between.

* **Paired equivalence** for per-realisation values of two models driven by
  the *same* noise: the margin comes from the paired differences, never from
  the spread of either model across realisations (which is ~100 times wider:
  the noise realisation dominates every metric, and cancels in the pair).
  Full vs reduced: the margin is the difference the rigid body's known terms
  explain (the exact twin minus the reduced model, paired) plus both paired
  95 % half-widths.  With d the paired differences and [lo, hi] their 95 %
  t-interval: pass when [lo, hi] lies inside +-margin, fail when it lies
  wholly outside, inconclusive otherwise, and then the number of realisations
  the check would need is stated.  A two one-sided tests (TOST) equivalence test.

* **Paired shift** for a number that should be reproduced exactly (the full
  model against its exact twin, same noise): it fails when the paired mean
  difference lies outside its own 95 % interval widened by the twin's
  measured floor.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

from cipcore.stats import ci95_half_width

PASS, FAIL, INCONCLUSIVE = "pass", "fail", "inconclusive"
#: a check that does not judge this engine, with the reason in its details (an exact-twin
#: check of an engine judged by time-step refinement); it counts as neither pass nor fail
NOT_APPLICABLE = "n/a"


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
    return ci95_half_width(x, finite_only=True)


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


def needed_realizations(d: np.ndarray, margin: float) -> int | None:
    """Realisations a paired TOST would need to conclude equivalence within +-margin.

    n with t_{0.975, n-1} s_d / sqrt(n) <= margin - |mean d| (s_d the paired
    differences' SD, assumed unchanged); None if |mean d| >= margin (no size passes).
    """
    from scipy.stats import t as student_t

    d = np.asarray(d, dtype=float)
    d = d[np.isfinite(d)]
    room = margin - abs(d.mean())
    if d.size < 2 or room <= 0:
        return None
    s = d.std(ddof=1)
    if s == 0:
        return int(d.size)
    n = max(2, int(np.ceil((1.96 * s / room) ** 2)))
    while student_t.ppf(0.975, n - 1) * s / np.sqrt(n) > room:
        n += 1
    return n


def tost_status(lo: float, hi: float, margin: float) -> str:
    """The verdict of an equivalence test (TOST) from a 95 % interval [lo, hi] of a
    difference and its margin: PASS when the interval lies inside +- margin, FAIL when
    it lies wholly outside, INCONCLUSIVE otherwise."""
    if lo >= -margin and hi <= margin:
        return PASS
    if lo > margin or hi < -margin:
        return FAIL
    return INCONCLUSIVE


def paired_equivalence(
    full: np.ndarray,
    reference: np.ndarray,
    margin: float | None = None,
    *,
    expected: np.ndarray | None = None,
    floor: float = 0.0,
) -> tuple[str, dict]:
    """Paired TOST of per-realisation values under the same noise (module docstring).

    With d = full - reference and [lo, hi] its 95 % t-interval, the margin is

    * ``margin`` when given;
    * else, with ``expected`` the per-realisation differences the known terms
      predict (e.g. twin - reduced), |mean e| + hw(e) + hw(d) + floor: the
      difference the known terms explain plus both paired uncertainties;
    * else 2 hw(d) + floor: agreement within the run's own paired resolution.

    pass when [lo, hi] lies inside +-margin, fail when it lies wholly outside,
    inconclusive otherwise, with the number of realisations it would need.
    """
    a = np.asarray(full, dtype=float).ravel()
    b = np.asarray(reference, dtype=float).ravel()
    ok = np.isfinite(a) & np.isfinite(b)
    a, b = a[ok], b[ok]
    if a.size < 2:
        return INCONCLUSIVE, {"n": int(a.size)}
    d = a - b
    hw = t_half_width(d)
    if margin is None and expected is not None:
        e = np.asarray(expected, dtype=float).ravel()
        e = e[np.isfinite(e)]
        margin = abs(float(e.mean())) + t_half_width(e) + hw + floor
        rule = "known terms' difference + paired half-widths"
    elif margin is None:
        margin = 2.0 * hw + floor
        rule = "twice the paired half-width"
    else:
        rule = "given"
    lo, hi = d.mean() - hw, d.mean() + hw
    status = tost_status(lo, hi, margin)
    n = a.size
    out = {
        "n": int(n),
        "full": {"value": float(a.mean()), "se": float(a.std(ddof=1) / np.sqrt(n))},
        "reduced": {"value": float(b.mean()), "se": float(b.std(ddof=1) / np.sqrt(n))},
        "difference": {"value": float(d.mean()), "se": float(d.std(ddof=1) / np.sqrt(n))},
        "difference_mean": float(d.mean()),
        "difference_ci95": [float(lo), float(hi)],
        "margin": float(margin),
        "margin_rule": rule,
    }
    if status == INCONCLUSIVE:
        out["needed_realizations"] = needed_realizations(d, margin)
    return status, out


def paired_shift(value: np.ndarray, reference: np.ndarray, floor: float = 0.0) -> tuple[str, dict]:
    """Has a per-realisation number moved against a reference that should equal it?

    For the full model against its exact twin (same noise): d = value - reference;
    pass when |mean d| <= hw(d) + floor (zero lies in the paired 95 % interval,
    widened by the twin's measured floor), fail otherwise.
    """
    a = np.asarray(value, dtype=float).ravel()
    b = np.asarray(reference, dtype=float).ravel()
    if a.shape != b.shape or not (np.isfinite(a) == np.isfinite(b)).all():
        return FAIL, {"n": int(a.size), "reason": "different or non-finite values"}
    ok = np.isfinite(a)
    d = a[ok] - b[ok]
    hw = t_half_width(d) if d.size > 1 else 0.0
    hw = 0.0 if not np.isfinite(hw) else hw
    mean = float(d.mean()) if d.size else 0.0
    status = PASS if abs(mean) <= hw + floor else FAIL
    return status, {
        "n": int(d.size),
        "difference_mean": mean,
        "difference_ci95": [mean - hw, mean + hw],
        "floor": floor,
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
    """exp(mean(log x)) of positive values (paper Fig. 6 plots log RMS)."""
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
