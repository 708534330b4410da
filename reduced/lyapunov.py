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

from collections.abc import Sequence

import numpy as np

from cipcore.driver import run_blocks
from cipcore.noise import GainNoise, make_noise
from cipcore.params import STEPPERS, BalanceParams, ParameterError, check_choice, whole_steps
from cipcore.results import CriticalGain, LyapunovResult, check_transient
from cipcore.scenario import Execution, Scenario
from cipcore.schema import check_duration
from cipcore.seeds import purpose_rng, tangent_rng
from cipcore.stats import mean_ci95

from ._kernels import advance_errors
from .simulate import n_controllers


def lyapunov(
    scenario: Scenario,
    *,
    transient: float | None = None,
    renorm_interval: float | None = None,
    stepper: str = "semi-implicit",
    noise: GainNoise | None = None,
    execution: Execution = Execution(),
) -> LyapunovResult:
    """Largest Lyapunov exponent lambda1 (1/s) by Benettin renormalisation.

    Parameters
    ----------
    scenario : the model ("single" or "coupled"), its parameters (nu = 0 gives the
        noise-free exponent, equal to the rightmost characteristic root,
        :mod:`reduced.stability`), the simulated time per realisation in s
        (transient included), the independent noise realisations (one exponent
        each) and the noise seed; the initial tangent vector of realisation r comes
        from an independent stream ``SeedSequence(seed, spawn_key=(r, 1))``.  The
        scenario's amplitude is not used (the tangent dynamics are linear).
    transient : s discarded at the start (default min(10 s, duration / 10)).
    renorm_interval : s between renormalisations (default tau).
    stepper : "semi-implicit" or "explicit".
    noise : a :class:`GainNoise` to consume instead of the seed's.
    execution : worker threads and a progress bar; the numbers do not depend on it.
    """
    return lyapunov_gains(
        scenario, (scenario.params,), transient=transient, renorm_interval=renorm_interval,
        stepper=stepper, noise=noise, execution=execution,
    )[0]  # fmt: skip


def lyapunov_gains(
    scenario: Scenario,
    params_seq: Sequence[BalanceParams],
    *,
    transient: float | None = None,
    renorm_interval: float | None = None,
    stepper: str = "semi-implicit",
    noise: GainNoise | None = None,
    execution: Execution = Execution(),
) -> list[LyapunovResult]:
    """:func:`lyapunov` at several parameter sets (e.g. gains) under the same draws.

    Each chunk of a realisation's draws is made once and advances every parameter
    set, so the draws are shared (common random numbers, as separate :func:`lyapunov`
    calls with one seed draw them) and made once instead of once per set; each
    result equals :func:`lyapunov`'s for its parameters alone.  The sets share the
    step ``dt`` and the delay ``tau`` (s).  ``scenario`` gives the model, duration,
    realisations and seed (its ``params`` are not used: ``params_seq`` replaces
    them); the other arguments as :func:`lyapunov`.

    The function is long because the parameter sets' checks, the tangent start and the
    Benettin accumulation share the run's arrays by closure.
    """
    model, duration = scenario.model, scenario.duration
    seed, n_realizations = scenario.seed, scenario.realizations
    params_seq = tuple(params_seq)
    if not params_seq:
        raise ParameterError("params_seq must hold at least one parameter set")
    params = params_seq[0]
    for p in params_seq[1:]:
        if p.dt != params.dt or p.delay_steps != params.delay_steps:
            raise ParameterError(
                f"every parameter set must share dt and tau (dt {params.dt} s, tau "
                f"{params.tau} s), got dt {p.dt} s, tau {p.tau} s"
            )
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
    ng = len(params_seq)

    y = np.empty((ng, nreal, 2 * nc))
    hist = np.empty((ng, nreal, nc, d))
    for r in range(nreal):
        rng = tangent_rng(noise.seed, noise.first_realization + r)
        y[:, r] = rng.standard_normal(2 * nc)
        hist[:, r] = rng.standard_normal((nc, d))
    logsum = np.zeros((ng, nreal))
    semi = stepper == "semi-implicit"

    def work(block: slice, xi: np.ndarray, n0: int) -> None:
        for g, p in enumerate(params_seq):
            advance_errors(
                xi, y[g, block], hist[g, block], n0 % d, p.law, semi, n0, renorm_steps,
                transient_steps, logsum[g, block],
            )  # fmt: skip

    run_blocks(noise, n_steps, work, threads=execution.threads,
               progress=execution.progress and "lyapunov")  # fmt: skip
    if not np.isfinite(logsum).all():
        g = int(np.flatnonzero(~np.isfinite(logsum).all(axis=1))[0])
        p = params_seq[g]
        raise ParameterError(
            f"alpha, beta, gamma, nu: the tangent dynamics left float64's range within one "
            f"renormalisation interval ({renorm:g} s: |lambda1| above {709.0 / renorm:.3g} "
            f"1/s) at alpha {p.alpha:g} 1/s^2, beta {p.beta:g} 1/s^2, gamma {p.gamma:g} 1/s, "
            f"nu {p.nu:g} s^1/2; the reduced model cannot measure lambda1 there (bring them "
            "nearer the paper's, or shorten renorm_interval)"
        )
    # accumulation starts at the first renormalisation after the transient
    start = (transient_steps // renorm_steps) * renorm_steps
    t_measured = (n_steps - start) * params.dt
    last_renorm = (n_steps // renorm_steps) * renorm_steps
    out = []
    for g, p in enumerate(params_seq):
        # the last partial interval is measured by the final norm
        final = np.sqrt((y[g] ** 2).sum(axis=1) + (hist[g] ** 2).sum(axis=(1, 2)))
        if n_steps > last_renorm and n_steps > transient_steps:
            logsum[g] += np.log(final)
        per = logsum[g] / t_measured
        mean, ci = mean_ci95(per)
        out.append(LyapunovResult(
            lambda1=mean, ci95=ci, per_realization=per, duration=duration, transient=transient,
            model=model, params=p.as_dict(), seed=noise.seed,
        ))  # fmt: skip
    return out


def numerical_setting(
    params: BalanceParams,
    duration: float,
    n_realizations: int,
    transient: float | None = None,
    stepper: str = "semi-implicit",
) -> dict:
    """The numerical setting a lambda1 (and so a beta*) is computed in, each item stated.

    The paper (section 3.1, eq. (3) and (5)) computes lambda1 "numerically" without
    naming any of these; beta* depends on them (issue: where the paper's beta* comes
    from), so every number cipval prints beside a beta* carries this record.
    """
    return {
        "estimator": "Benettin: the error coordinates (e_i, e_i') and their delay history "
        "of tau/dt past errors renormalised to unit Euclidean norm every tau, the log norms "
        "accumulated after the transient; mean over realisations (Student-t 95 % CI)",
        "dt_s": params.dt,
        "tau_s": params.tau,
        "delay_steps": params.delay_steps,
        "noise": "R_n = 1 + nu xi_n / sqrt(dt): one standard normal xi_n per step, held "
        "over the step (a white noise of unit intensity, variance 1/dt per step)",
        "nu": params.nu,
        "stepper": stepper,
        "duration_s": float(duration),
        "transient_s": check_transient(transient, duration),
        "realizations": int(n_realizations),
    }


def critical_gain(
    scenario: Scenario,
    beta_range: tuple[float, float],
    *,
    target: float = 5e-4,
    n_gains: int = 7,
    n_bootstrap: int = 2000,
    execution: Execution = Execution(),
) -> CriticalGain:
    """The gain beta* at which lambda1(beta) = ``target`` (paper Fig. 3: 5e-4).

    lambda1 is evaluated at ``n_gains`` gains spread over ``beta_range`` with
    the same noise realisations at every gain (the scenario's parameters with the
    gain replaced; its duration, realisations and seed); a quadratic (or, for
    fewer than four gains, linear) least-squares fit of lambda1 against beta is
    solved for the target.  The fit is repeated on ``n_bootstrap`` bootstrap
    resamples of the realisations to give the uncertainty.  Raises
    :class:`ParameterError` when the target is not crossed within ``beta_range``.
    """
    model, base, seed = scenario.model, scenario.params, scenario.seed
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
    gains = [base.with_(beta=float(b)) for b in betas]
    for res in lyapunov_gains(scenario, gains, execution=execution):
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
    n = per_arr.shape[1]
    idx = np.stack([rng.integers(0, n, n) for _ in range(n_bootstrap)])  # the draws, in order
    boots_arr = _solve_fits(betas, per_arr[:, idx].mean(axis=2), target, deg)
    boots_arr = boots_arr[np.isfinite(boots_arr)]
    ci = (float(np.percentile(boots_arr, 2.5)), float(np.percentile(boots_arr, 97.5)))
    return CriticalGain(
        beta_star=float(beta_star), std=float(boots_arr.std(ddof=1)), ci95=ci, target=target,
        betas=betas, lambdas=mean, ci95s=np.array(cis), model=model, duration=scenario.duration,
        n_realizations=per_arr.shape[1], seed=seed,
    )  # fmt: skip


def _solve_fits(betas: np.ndarray, lams: np.ndarray, target: float, deg: int) -> np.ndarray:
    """Root of polyfit(betas, lams[:, j], deg) - target inside [min(betas), max(betas)] for
    every column j of ``lams`` (gains, B), the one nearest the data's own crossing; NaN
    where there is none.

    One least-squares call for every column and one batched eigenvalue call for the
    fits' companion matrices (those :func:`numpy.roots` forms); a column whose fit is
    degenerate (leading coefficient 0, or not finite) goes through :func:`numpy.roots`.
    """
    coef = np.polyfit(betas, lams, deg)  # (deg + 1, B)
    coef[-1] -= target
    real = np.full((lams.shape[1], deg), np.nan)
    imag = np.zeros_like(real)
    ok = (coef[0] != 0) & np.isfinite(coef).all(axis=0)
    for j in np.flatnonzero(~ok & np.isfinite(coef).all(axis=0)):  # a lower degree
        r = np.roots(coef[:, j])
        real[j, : r.size], imag[j, : r.size] = r.real, r.imag
    c = coef[:, ok].T  # (B', deg + 1)
    comp = np.zeros((c.shape[0], deg, deg))
    comp[:, 0, :] = -c[:, 1:] / c[:, :1]
    comp[:, np.arange(1, deg), np.arange(deg - 1)] = 1.0
    roots = np.linalg.eigvals(comp)  # (B', deg)
    real[ok], imag[ok] = roots.real, roots.imag
    with np.errstate(invalid="ignore"):
        usable = (np.abs(imag) < 1e-9) & (real >= betas.min()) & (real <= betas.max())
    guess = betas[np.argmin(np.abs(lams - target), axis=0)]
    dist = np.where(usable, np.abs(real - guess[:, None]), np.inf)
    best = np.argmin(dist, axis=1)
    found = real[np.arange(real.shape[0]), best]
    return np.where(usable.any(axis=1), found, np.nan)


def _solve_fit(betas: np.ndarray, lam: np.ndarray, target: float, deg: int) -> float | None:
    """:func:`_solve_fits` of one set of lambda1 values; None where the fit has no root
    inside the gains."""
    b = _solve_fits(betas, np.asarray(lam, dtype=float)[:, None], target, deg)[0]
    return None if np.isnan(b) else float(b)
