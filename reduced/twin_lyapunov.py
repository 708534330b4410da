"""lambda1 of a rigid body's exact linear twin, realisation by realisation as the engine's.

The twin (:mod:`reduced.twin`) steps the rigid body's linear terms the way the
engine steps them.  The controlled CIP is linear about upright and its noise is
multiplicative (paper eq. (5): u = beta (1 + nu xi(t)) e(t - tau)), so the twin's
state *is* its tangent dynamics, and Benettin's method on it follows the engine's
Benettin estimate (:func:`cip.lyapunov.lyapunov_full`) realisation by realisation
when both start from the same deviation under the same noise and are renormalised
in the same norm at the same times.  That pairing is what makes the twin a control
variate of the engine's lambda1 (:mod:`validation.checks.multifidelity`): the
per-realisation exponents of an engine and its exact twin agree to the engine's
precision, so a few engine realisations and many twin realisations estimate the
engine's lambda1 as well as many engine realisations.

Everything is the engine estimator's: the initial deviation
(:func:`cipcore.seeds.tangent_deviation`), the renormalisation every tau (d
steps, compiled: :func:`reduced._twin_kernel._benettin`), the norm (all terms in
m or m/s)::

    sqrt( sum_i (x_i - mean_j x_j)^2 + e_i^2 + v_i^2 + e_i'^2
          + sum over the delay buffer (steps n - d .. n - 1) of e_i^2 + e_i'^2 ),

x the carts, v their velocities, e = L theta the balancing errors (the engine's
(L theta) and (L theta') terms), the carts' common drift dropped at each
renormalisation (it is neutral), and the transient (default min(10 s, duration / 10),
whole chunks of d steps) discarded.
"""

from __future__ import annotations

import numpy as np

from cipcore.driver import CHUNK_STEPS, run_blocks
from cipcore.noise import GainNoise
from cipcore.params import ParameterError, whole_steps
from cipcore.results import LyapunovResult, check_transient
from cipcore.scenario import Execution, Scenario
from cipcore.schema import check_duration
from cipcore.seeds import tangent_deviation
from cipcore.stats import mean_ci95

from ._twin_kernel import KERNELS, renormalise_twin
from .simulate import n_controllers
from .twin import TWIN_SCHEMES, TwinParams, twin_coefficients


def initial_deviation(seed: int, n_realizations: int, n_controllers: int,
                      delay_steps: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:  # fmt: skip
    """The twin's (state (R, C, 4), delayed errors (R, C, d), their rates (R, C, d)) at
    the engine's initial deviation (:func:`cipcore.seeds.tangent_deviation`), unscaled:
    carts and velocities at rest, the rates' buffer at rest as the engine's."""
    state = np.zeros((n_realizations, n_controllers, 4))
    hist = np.empty((n_realizations, n_controllers, delay_steps))
    for r in range(n_realizations):
        e0, h = tangent_deviation(seed, r, n_controllers, delay_steps)
        state[r, :, 1] = e0
        hist[r] = h.T
    return state, hist, np.zeros_like(hist)


def _check_inputs(scenario: Scenario, twin: TwinParams, epsilon: float) -> None:
    """A one-line ParameterError naming what does not fit :func:`lyapunov_twin`."""
    dt = scenario.params.dt
    if abs(twin.dt - dt) > 1e-15:
        raise ParameterError(f"twin.dt must equal the controller's dt = {dt:g} s, got {twin.dt:g}")
    if twin.rod and n_controllers(scenario.model) != 2:
        raise ParameterError(f"a rod needs the coupled model, got model {scenario.model!r}")
    if not (0 < epsilon < 1e-3):
        raise ParameterError(f"epsilon must be in (0, 1e-3) m, got {epsilon}")


def lyapunov_twin(
    scenario: Scenario,
    twin: TwinParams,
    *,
    epsilon: float = 1e-7,
    transient: float | None = None,
    execution: Execution = Execution(),
) -> LyapunovResult:
    """lambda1 (1/s) of ``twin`` by Benettin renormalisation, paired with the engine's.

    Parameters
    ----------
    scenario : the model, controller (beta, nu, tau, dt), duration (s, transient
        included), realisations and noise seed, as for
        :func:`cip.lyapunov.lyapunov_full`; the amplitude is not used.
    twin : the rigid body's linear terms and stepper, stepped at ``scenario.params.dt``
        (``twin.dt`` must equal it: the delay is a whole number of the engine's steps).
    epsilon : the deviation's norm after each renormalisation (m); the twin is
        linear, so lambda1 does not depend on it beyond rounding: the engine's value
        is the natural choice.
    transient : s discarded at the start (default min(10 s, duration / 10)).
    execution : worker threads; the numbers do not depend on them.

    Returns
    -------
    LyapunovResult
        Per-realisation exponents (1/s), their mean and Student-t 95 % interval.
    """
    params = scenario.params
    nc = n_controllers(scenario.model)
    _check_inputs(scenario, twin, epsilon)
    duration = check_duration(scenario.duration)
    n_steps = whole_steps("duration", duration, params.dt)
    transient = check_transient(transient, duration)
    transient_steps = round(transient / params.dt)
    noise = GainNoise(scenario.seed, scenario.realizations, nc)
    nreal, d = noise.n_realizations, params.delay_steps
    state, hist, rates = initial_deviation(scenario.seed, nreal, nc, d)
    coef = twin_coefficients(twin, params)
    minv, mstep = twin.inverse_mass(), twin.step_matrix()
    benettin_twin = KERNELS[TWIN_SCHEMES[twin.integrator]][1]
    logsum = np.zeros(nreal)
    start = (transient_steps // d) * d
    renormalise_twin(state, hist, rates, epsilon)  # the start, at norm epsilon

    def work(block: slice, xi: np.ndarray, step: int) -> None:
        bad = benettin_twin(xi, state[block], hist[block], rates[block], coef, minv, mstep,
                            step, transient_steps, epsilon, logsum[block])  # fmt: skip
        if bad >= 0:
            raise FloatingPointError(f"non-finite twin state at t = {bad * params.dt:.4g} s")

    # chunks of whole delays (the kernel renormalises every d steps inside a chunk, and
    # at the run's end)
    chunk = d * max(1, CHUNK_STEPS // d)
    run_blocks(noise, n_steps, work, threads=execution.threads, chunk_steps=chunk)
    per = logsum / ((n_steps - start) * params.dt)
    mean, ci = mean_ci95(per)
    return LyapunovResult(
        lambda1=mean, ci95=ci, per_realization=per, duration=duration, transient=transient,
        model=scenario.model, params={**params.as_dict(), "twin": twin.as_dict()},
        seed=scenario.seed,
    )  # fmt: skip
