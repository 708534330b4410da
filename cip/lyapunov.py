"""lambda1 of the full MuJoCo CIP by small-amplitude Benettin renormalisation.

The upright rest state is a fixed point of the controlled CIP for every noise
realisation (the control is proportional to the balancing error), so the
tangent dynamics are those of small deviations from it.  Each realisation
starts at a random deviation of size ``epsilon``; after every chunk of
tau (= the renormalisation interval) the deviation, i.e. (cart positions
relative to their mean, angles, all velocities) *and* the delay buffer of
balancing errors, is scaled back to norm ``epsilon`` and log(norm/epsilon) is
accumulated.  The common translation of the carts is neutral (cart and tip may translate
together freely; left in, it grows until e is rounding noise and the estimate
creeps to 0 like 1/T) and is removed at each renormalisation.

Norm (all terms in m or m/s): sqrt(sum (x_Mi - mean x_M)^2 + (L theta_i)^2 +
v_Mi^2 + (L theta_i')^2 + sum over the buffer of e^2 + e'^2).
"""

from __future__ import annotations

import warnings

import numpy as np

from cip.model import CIPParams
from cip.runner import CIPRunner, RigidBody, RolloutBackend
from cip.simulate import DivergenceWarning
from cipcore.driver import realization_blocks, run_blocks
from cipcore.models import get_model
from cipcore.noise import ArrayNoise, GainNoise, StackedNoise, make_noise
from cipcore.params import BalanceParams, ParameterError, whole_steps
from cipcore.results import LyapunovResult, check_transient
from cipcore.scenario import Execution, Scenario
from cipcore.schema import check_duration
from cipcore.seeds import tangent_deviation
from cipcore.stats import mean_ci95


class _Renormaliser:
    """The Benettin deviation of one runner's realisations: its norm and its rescaling.

    The norm (m, per realisation) weighs the carts' positions (their common drift
    dropped: it is neutral), the angles times L, the cart velocities, the angular
    velocities times L and the delay histories.  Called after every chunk (tau of
    simulated time), so the index work is done once: one gather for the norm and,
    where the cart and pendulum coordinates fill the state's qpos and qvel (the CIP
    models), one in-place product for the rescaling.
    """

    def __init__(self, r: CIPRunner) -> None:
        nc = r.nc
        self.cols = np.concatenate([r.i_x, r.i_th, r.i_vx, r.i_om])
        self.weights = np.concatenate([np.ones(nc), np.full(nc, r.L), np.ones(nc),
                                       np.full(nc, r.L)])  # fmt: skip
        lo, hi = int(self.cols.min()), int(self.cols.max()) + 1
        whole = np.array_equal(np.sort(self.cols), np.arange(lo, hi))
        self.block = slice(lo, hi) if whole else None
        self.mean: np.ndarray | None = None

    def norm(self, r: CIPRunner) -> np.ndarray:
        """The deviation's norm (R,) of the runner's state."""
        nc = r.nc
        g = r.state[:, self.cols]
        self.mean = g[:, :nc].mean(axis=1, keepdims=True)
        g[:, :nc] -= self.mean
        q = ((g * self.weights) ** 2).reshape(g.shape[0], 4, nc).sum(axis=2)
        s = q[:, 0] + q[:, 1]
        s += q[:, 2]
        s += q[:, 3]
        s += (r.e_hist**2).sum((1, 2)) + (r.edot_hist**2).sum((1, 2))
        return np.sqrt(s)

    def rescale(self, r: CIPRunner, c: np.ndarray) -> None:
        """Scale every realisation's deviation by c (R,), dropping the carts' common
        drift; right after :meth:`norm` of the same state."""
        if self.mean is None:
            raise RuntimeError("rescale needs the norm of the same state first")
        st = r.state
        st[:, r.i_x] -= self.mean
        if self.block is not None:
            st[:, self.block] *= c[:, None]
        else:
            for idx in (r.i_x, r.i_th, r.i_vx, r.i_om):
                st[:, idx] *= c[:, None]
        r.e_hist *= c[:, None, None]
        r.edot_hist *= c[:, None, None]
        self.mean = None

    def rest(self, r: CIPRunner, rows: np.ndarray) -> None:
        """Put realisations ``rows`` (a boolean mask) at the upright rest state, with no
        deviation and an empty delay history: a realisation whose state went non-finite
        is stepped on there (its exponent is already +inf) so that the engine never
        receives a non-finite state, and the other realisations run to the end."""
        st = r.state
        idx = np.flatnonzero(rows)
        sub = st[idx]
        sub[~np.isfinite(sub)] = 0.0
        sub[:, self.cols] = 0.0
        st[idx] = sub
        r.e_hist[idx] = 0.0
        r.edot_hist[idx] = 0.0


def lyapunov_full(
    scenario: Scenario,
    *,
    body: RigidBody = RigidBody(),
    epsilon: float = 1e-7,
    transient: float | None = None,
    execution: Execution = Execution(),
    noise: GainNoise | ArrayNoise | StackedNoise | None = None,
    betas: np.ndarray | None = None,
) -> LyapunovResult:
    """Largest Lyapunov exponent (1/s) of the MuJoCo CIP about upright.

    Same noise draws as :func:`reduced.lyapunov.lyapunov` for the same scenario
    (the initial deviation differs: here it is a random small tilt; the
    scenario's amplitude is not used).  ``epsilon`` (m) is the deviation size kept
    by renormalisation: small enough for the linear regime (theta ~ epsilon / L).
    ``body`` as in :func:`cip.simulate.simulate_full`; ``transient`` (s) is
    discarded at the start (default min(10 s, duration / 10)).

    ``noise`` (default: the scenario's seed and realisations) and ``betas`` (R,), a gain
    (1/s^2) per realisation instead of the scenario's, run several gains and seeds in
    one batch (a :class:`cipcore.noise.StackedNoise`): realisation r draws its noise and
    its initial deviation from its own stream (``noise.stream(r)``), so its exponent is
    the one it has run alone.  The step-bound engines (a batch of worlds per step) then
    step once for all of them, and the driver's threads share them evenly.

    A realisation whose state goes non-finite (an engine's fault: the deviation stays
    in the linear regime) gets the exponent +inf and its time in ``diverged_at``; it
    rests upright from then on, so the engine never receives a non-finite state, and
    every other realisation runs to the end with the exponent it has alone, whatever
    the threads.

    The function is long because the chunk callback (the renormalisation, and a
    realisation gone non-finite put at rest) shares the run's arrays by closure.
    """
    model, params, seed = scenario.model, scenario.params, scenario.seed
    threads, backend, mj_model = execution.threads, body.backend, body.mj_model
    nc = get_model(model).n_controllers
    duration = check_duration(scenario.duration)
    n_steps = whole_steps("duration", duration, params.dt)
    transient = check_transient(transient, duration)
    if not (0 < epsilon < 1e-3):
        raise ParameterError(f"epsilon must be in (0, 1e-3) m, got {epsilon}")
    physical = body.physical or CIPParams.from_reduced(params)
    noise = make_noise(noise, seed, scenario.realizations, nc)
    n_realizations = noise.n_realizations
    if betas is not None and np.size(betas) != n_realizations:
        raise ParameterError(f"betas must give one gain per realisation ({n_realizations}), "
                             f"got {np.size(betas)}")  # fmt: skip
    transient_steps = round(transient / params.dt)
    logsum = np.zeros(n_realizations)
    # each block's runner is built here, before the driver's threads start (a backend may
    # fork worker processes, cip.workers: never beside running threads)
    gains = None if betas is None else np.ravel(betas)
    runners = {}
    for block in realization_blocks(n_realizations, threads):
        own = None if gains is None else gains[block]
        runners[block.start] = _start(model, params, physical, block, noise, epsilon, backend,
                                      mj_model, own)  # fmt: skip
    d = params.delay_steps
    # accumulation starts with the first chunk that ends after the transient
    start = (transient_steps // d) * d

    # per realisation: the end (s) of the chunk after which its state was first
    # non-finite (NaN: never); from then on it rests upright and its exponent is +inf
    diverged_at = np.full(n_realizations, np.nan)

    def work(block: slice, xi: np.ndarray, step: int) -> None:
        r, renorm = runners[block.start]
        n = xi.shape[1]
        r.advance(xi)
        norm = renorm.norm(r)
        live = np.isnan(diverged_at[block]) & np.isfinite(norm)
        if live.all():
            if step + n > transient_steps:
                logsum[block] += np.log(norm / epsilon)
            renorm.rescale(r, epsilon / norm)
            return
        newly = ~live & np.isnan(diverged_at[block])
        diverged_at[block][newly] = (step + n) * params.dt
        kept = np.where(live, norm, epsilon)
        if step + n > transient_steps:
            logsum[block] += np.where(live, np.log(kept / epsilon), 0.0)
        renorm.rescale(r, np.where(live, epsilon / kept, 0.0))
        renorm.rest(r, ~live)

    run_blocks(noise, n_steps, work, threads=threads, chunk_steps=d,
               progress=execution.progress and "mujoco lyapunov")  # fmt: skip
    per = logsum / ((n_steps - start) * params.dt)
    fell = np.isfinite(diverged_at)
    per[fell] = np.inf
    if fell.any():
        k = int(np.nanargmin(diverged_at))
        warnings.warn(
            f"{body.name} lambda1 run: non-finite state in {int(fell.sum())} of "
            f"{n_realizations} realisations, first realisation {k} by t = {diverged_at[k]:.4g} "
            f"s; their exponents are +inf, the others ran to the end",
            DivergenceWarning,
            stacklevel=2,
        )
    with np.errstate(invalid="ignore"):  # an infinite exponent: an infinite mean, no interval
        mean, ci = mean_ci95(per)
    return LyapunovResult(
        lambda1=mean, ci95=ci, per_realization=per, duration=duration, transient=transient,
        model=model, params={**params.as_dict(), "physical": physical.as_dict(),
                             **({} if gains is None else {"betas": gains.tolist()})},
        seed=seed, diverged_at=diverged_at if fell.any() else None,
    )  # fmt: skip


def _start(
    model: str,
    params: BalanceParams,
    physical: CIPParams,
    block: slice,
    noise: GainNoise | ArrayNoise | StackedNoise,
    epsilon: float,
    backend: type[RolloutBackend] | None = None,
    mj_model: object = None,
    betas: np.ndarray | None = None,
) -> tuple[CIPRunner, _Renormaliser]:
    """A runner for realisations ``block`` at a random deviation of norm epsilon, and
    the renormaliser of its deviation; ``betas`` the block's gains (None: the params').

    Angles and delay history of realisation k: :func:`cipcore.seeds.tangent_deviation`
    of its noise stream ``noise.stream(k)`` = (seed, index) (the stream
    ``SeedSequence(seed, spawn_key=(index, 1))``; in the coupled model both angles start
    equal, on the rod constraint to first order).
    """
    r = CIPRunner(
        model, params, physical, block.stop - block.start, 0.0, threads=1, backend=backend,
        mj_model=mj_model, betas=betas,
    )  # fmt: skip
    for j, k in enumerate(range(block.start, block.stop)):
        e0, r.e_hist[j] = tangent_deviation(*noise.stream(k), r.nc, r.d)
        r.state[j, r.i_th] = e0 / physical.pendulum_length
    renorm = _Renormaliser(r)
    renorm.rescale(r, epsilon / renorm.norm(r))
    return r, renorm
