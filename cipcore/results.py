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
    """lambda1 (1/s): mean over realisations and its 95 % confidence interval."""

    lambda1: float
    ci95: tuple[float, float]
    per_realization: np.ndarray
    duration: float
    transient: float
    model: str
    params: dict = field(default_factory=dict)
    seed: int = 0

    @property
    def sem(self) -> float:
        n = len(self.per_realization)
        return float(np.std(self.per_realization, ddof=1) / np.sqrt(n)) if n > 1 else float("nan")

    def part(self, realizations: slice, beta: float, seed: int) -> LyapunovResult:
        """The result of ``realizations`` alone, run at gain ``beta`` (1/s^2) from noise
        ``seed``: one scenario of a batch of several (``betas`` per realisation)."""
        per = np.asarray(self.per_realization)[realizations]
        mean, ci = mean_ci95(per)
        params = {k: v for k, v in self.params.items() if k != "betas"}
        return replace(self, lambda1=mean, ci95=ci, per_realization=per,
                       params={**params, "beta": beta}, seed=seed)  # fmt: skip

    def as_dict(self) -> dict:
        d = asdict(self)
        d["per_realization"] = self.per_realization.tolist()
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
