"""Largest Lyapunov exponent lambda1 of the reduced models (paper section 3.1).

    lambda1 = lim_{t -> inf} (1/t) log || Delta q(t) ||

Benettin's method on the *error* coordinates (e_i, e_i') together with their
delay history: every ``renorm_interval`` the whole state (including the d
stored past errors) is renormalised to unit Euclidean norm and the log of the
norm is accumulated.  Integrating the errors, not absolute positions, avoids
the neutral common drift of tip and bases (they may translate together freely), which would
otherwise make the estimate creep to 0 like 1/T.

Each realisation gives one exponent; the result is their mean with a
Student-t 95 % confidence interval.  Near the threshold the estimate converges
slowly (on-off intermittency), so the interval, not the mean alone, is the
result.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from cipcore.driver import run_blocks
from cipcore.noise import GainNoise, make_noise
from cipcore.params import STEPPERS, BalanceParams, ParameterError, check_choice, whole_steps
from cipcore.results import LyapunovResult, check_transient
from cipcore.schema import check_duration
from cipcore.seeds import purpose_rng, tangent_rng
from cipcore.stats import mean_ci95

from ._kernels import advance_errors
from .simulate import n_controllers


def lyapunov(
    model: str,
    params: BalanceParams,
    duration: float = 200.0,
    n_realizations: int = 8,
    seed: int = 0,
    *,
    transient: float | None = None,
    renorm_interval: float | None = None,
    stepper: str = "semi-implicit",
    noise: GainNoise | None = None,
    threads: int | None = None,
    progress: bool = False,
) -> LyapunovResult:
    """Largest Lyapunov exponent lambda1 (1/s) by Benettin renormalisation.

    Parameters
    ----------
    model : "single" or "coupled".
    params : model parameters (nu = 0 gives the noise-free exponent, equal
        to the rightmost characteristic root, :mod:`reduced.stability`).
    duration : simulated time per realisation in s, transient included.
    n_realizations : independent noise realisations (one exponent each).
    seed : noise seed; the initial tangent vector of realisation r comes from
        an independent stream ``SeedSequence(seed, spawn_key=(r, 1))``.
    transient : s discarded at the start (default min(10 s, duration / 10)).
    renorm_interval : s between renormalisations (default tau).
    stepper : "semi-implicit" or "explicit".
    """
    nc = n_controllers(model)
    check_choice("stepper", stepper, STEPPERS)
    duration = check_duration(duration)
    n_steps = whole_steps("duration", duration, params.dt)
    transient = check_transient(transient, duration)
    transient_steps = round(transient / params.dt)
    renorm = params.tau if renorm_interval is None else float(renorm_interval)
    if not (params.dt <= renorm <= duration - transient):
        raise ParameterError(
            f"renorm_interval must be in [dt, duration - transient] s, got {renorm_interval}"
        )
    renorm_steps = whole_steps("renorm_interval", renorm, params.dt)
    noise = make_noise(noise, seed, n_realizations, nc)
    nreal = noise.n_realizations
    d = params.delay_steps

    y = np.empty((nreal, 2 * nc))
    hist = np.empty((nreal, nc, d))
    for r in range(nreal):
        rng = tangent_rng(noise.seed, noise.first_realization + r)
        y[r] = rng.standard_normal(2 * nc)
        hist[r] = rng.standard_normal((nc, d))
    logsum = np.zeros(nreal)
    semi = stepper == "semi-implicit"

    def work(block: slice, xi: np.ndarray, n0: int) -> None:
        advance_errors(
            xi, y[block], hist[block], n0 % d, params.alpha, params.beta, params.gamma,
            params.noise_scale, params.dt, semi, n0, renorm_steps, transient_steps,
            logsum[block],
        )  # fmt: skip

    run_blocks(noise, n_steps, work, threads=threads, progress=progress and "lyapunov")
    # the last partial interval is measured by the final norm
    final = np.sqrt((y**2).sum(axis=1) + (hist**2).sum(axis=(1, 2)))
    last_renorm = (n_steps // renorm_steps) * renorm_steps
    if n_steps > last_renorm and n_steps > transient_steps:
        logsum += np.log(final)
    # accumulation starts at the first renormalisation after the transient
    start = (transient_steps // renorm_steps) * renorm_steps
    t_measured = (n_steps - start) * params.dt
    per = logsum / t_measured
    mean, ci = mean_ci95(per)
    return LyapunovResult(
        lambda1=mean, ci95=ci, per_realization=per, duration=duration, transient=transient,
        model=model, params=params.as_dict(), seed=noise.seed,
    )  # fmt: skip


@dataclass
class CriticalGain:
    """beta* (1/s^2): the gain at which lambda1 equals ``target``.

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


def critical_gain(
    model: str,
    base: BalanceParams,
    beta_range: tuple[float, float],
    target: float = 5e-4,
    n_gains: int = 7,
    duration: float = 500.0,
    n_realizations: int = 16,
    seed: int = 0,
    *,
    n_bootstrap: int = 2000,
    threads: int | None = None,
    progress: bool = False,
) -> CriticalGain:
    """The gain beta* at which lambda1(beta) = ``target`` (paper Fig. 3: 5e-4).

    lambda1 is evaluated at ``n_gains`` gains spread over ``beta_range`` with
    the same noise realisations at every gain; a quadratic (or, for fewer than
    four gains, linear) least-squares fit of lambda1 against beta is solved for
    the target.  The fit is repeated on bootstrap resamples of the realisations
    to give the uncertainty.  Raises :class:`ParameterError` when the target is
    not crossed within ``beta_range``.
    """
    lo, hi = (float(v) for v in beta_range)
    if not (np.isfinite(lo) and np.isfinite(hi) and 0 <= lo < hi):
        raise ParameterError(
            f"beta_range must be two finite gains 0 <= low < high, got {beta_range}"
        )
    if n_gains < 2:
        raise ParameterError(f"n_gains must be >= 2, got {n_gains}")
    betas = np.linspace(lo, hi, n_gains)
    per = []
    cis = []
    for b in betas:
        res = lyapunov(
            model, base.with_(beta=float(b)), duration, n_realizations, seed,
            threads=threads, progress=progress,
        )  # fmt: skip
        per.append(res.per_realization)
        cis.append(res.ci95)
    per_arr = np.array(per)  # (gains, realisations)
    mean = per_arr.mean(axis=1)
    deg = 2 if n_gains >= 4 else 1
    beta_star = _solve_fit(betas, mean, target, deg)
    if beta_star is None:
        raise ParameterError(
            f"lambda1 does not cross target {target:g} in beta_range [{lo}, {hi}] "
            f"(lambda1 from {mean.min():.3g} to {mean.max():.3g} 1/s); widen beta_range"
        )
    rng = purpose_rng(seed, "bootstrap")
    boots = []
    for _ in range(n_bootstrap):
        idx = rng.integers(0, per_arr.shape[1], per_arr.shape[1])
        b = _solve_fit(betas, per_arr[:, idx].mean(axis=1), target, deg)
        if b is not None:
            boots.append(b)
    boots_arr = np.array(boots)
    ci = (float(np.percentile(boots_arr, 2.5)), float(np.percentile(boots_arr, 97.5)))
    return CriticalGain(
        beta_star=float(beta_star), std=float(boots_arr.std(ddof=1)), ci95=ci, target=target,
        betas=betas, lambdas=mean, ci95s=np.array(cis), model=model, duration=duration,
        n_realizations=per_arr.shape[1], seed=seed,
    )  # fmt: skip


def _solve_fit(betas: np.ndarray, lam: np.ndarray, target: float, deg: int) -> float | None:
    """Root of polyfit(betas, lam, deg) - target inside [min(betas), max(betas)]."""
    coef = np.polyfit(betas, lam, deg)
    coef[-1] -= target
    roots = np.roots(coef)
    real = roots[np.abs(roots.imag) < 1e-9].real
    inside = real[(real >= betas.min()) & (real <= betas.max())]
    if inside.size == 0:
        return None
    # the crossing nearest the data's own crossing
    guess = betas[np.argmin(np.abs(lam - target))]
    return float(inside[np.argmin(np.abs(inside - guess))])
