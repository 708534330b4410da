"""Result types every engine returns.

:class:`LyapunovResult` is the largest Lyapunov exponent lambda1 (1/s) of a
batch of realisations, whichever engine computed it: the mean over
realisations and its Student-t 95 % CI (:mod:`cipcore.stats`).
:class:`CriticalGain` is beta*, the gain at which lambda1 reaches a target.  Both are
plain records, importable without numba or an engine (the figure process unpickles them).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field, replace

import numpy as np

from .params import ParameterError
from .stats import mean_ci95


@dataclass
class LyapunovResult:
    """lambda1 (1/s): mean over realisations and its 95 % confidence interval.

    ``diverged_at`` (s, one per realisation, NaN where it stayed finite; None when every
    realisation did) is where an engine's Benettin run went non-finite: the end of the
    renormalisation interval after which its state was first non-finite.  Such a
    realisation's exponent is +inf (its deviation grew without bound), and so is lambda1.
    """

    lambda1: float
    ci95: tuple[float, float]
    per_realization: np.ndarray
    duration: float
    transient: float
    model: str
    params: dict = field(default_factory=dict)
    seed: int = 0
    diverged_at: np.ndarray | None = None

    @property
    def sem(self) -> float:
        n = len(self.per_realization)
        if n < 2 or not np.isfinite(self.per_realization).all():  # an infinite exponent: none
            return float("nan")
        return float(np.std(self.per_realization, ddof=1) / np.sqrt(n))

    def part(self, realizations: slice, beta: float, seed: int) -> LyapunovResult:
        """The result of ``realizations`` alone, run at gain ``beta`` (1/s^2) from noise
        ``seed``: one scenario of a batch of several (``betas`` per realisation)."""
        per = np.asarray(self.per_realization)[realizations]
        with np.errstate(invalid="ignore"):  # an infinite exponent: no interval
            mean, ci = mean_ci95(per)
        params = {k: v for k, v in self.params.items() if k != "betas"}
        at = None if self.diverged_at is None else np.asarray(self.diverged_at)[realizations]
        return replace(self, lambda1=mean, ci95=ci, per_realization=per,
                       params={**params, "beta": beta}, seed=seed,
                       diverged_at=None if at is None or np.isnan(at).all() else at)  # fmt: skip

    def divergence(self) -> str | None:
        """One line naming the realisations whose run went non-finite, and when; None if none."""
        if self.diverged_at is None:
            return None
        at = np.asarray(self.diverged_at, dtype=float)
        fell = np.flatnonzero(np.isfinite(at))
        shown = ", ".join(f"{int(k)} by t = {at[k]:.4g} s" for k in fell[:5])
        more = f" and {fell.size - 5} more" if fell.size > 5 else ""
        return (f"the engine's state went non-finite in {fell.size} of {at.size} realisations "
                f"({shown}{more})")  # fmt: skip

    def as_dict(self) -> dict:
        d = asdict(self)
        d["per_realization"] = self.per_realization.tolist()
        if self.diverged_at is None:
            d.pop("diverged_at")
        else:
            d["diverged_at"] = [None if np.isnan(v) else float(v) for v in self.diverged_at]
        d["ci95"] = [None if not np.isfinite(v) else float(v) for v in self.ci95]
        d["sem"] = None if not np.isfinite(self.sem) else self.sem
        d["n_realizations"] = len(self.per_realization)
        return d


def min_lyapunov_duration(tau: float, dt: float) -> float:
    """Shortest duration (s, whole steps of ``dt``) leaving one renormalisation interval
    tau after the default transient min(10 s, duration / 10)."""
    import math

    shortest = tau / 0.9 if tau < 90.0 else tau + 10.0
    return round(math.ceil(shortest / dt - 1e-9) * dt, 12)


def check_transient(transient: float | None, duration: float) -> float:
    """The transient to discard (s): default min(10 s, duration / 10), in [0, duration)."""
    t = min(10.0, duration / 10) if transient is None else float(transient)
    if not (0 <= t < duration):
        raise ParameterError(f"transient must be in [0, duration = {duration}) s, got {transient}")
    return t


@dataclass
class CriticalGain:
    """beta* (1/s^2): the gain at which lambda1 equals ``target``
    (:func:`reduced.lyapunov.critical_gain`, ``validation.paper``).

    ``ci95`` is a bootstrap percentile interval over realisations (the same
    realisations at every gain: common random numbers), ``std`` its standard
    deviation.  ``betas`` / ``lambdas`` / ``ci95s`` are the evaluations used.
    """

    beta_star: float
    std: float
    ci95: tuple[float, float]
    target: float
    betas: np.ndarray
    lambdas: np.ndarray
    ci95s: np.ndarray
    model: str
    duration: float
    n_realizations: int
    seed: int

    def as_dict(self) -> dict:
        d = asdict(self)
        for k in ("betas", "lambdas", "ci95s"):
            d[k] = np.asarray(d[k]).tolist()
        d["ci95"] = [float(v) for v in self.ci95]
        return d
