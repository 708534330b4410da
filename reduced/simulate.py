"""Time series of the reduced balancing models (paper eqs. (3), (5)).

    single:   x_T'' + gamma x_T' = alpha e(t),         x_M'' + gamma x_M' = beta R(t) e(t - tau)
    coupled:  2 q_T'' + 2 gamma q_T' = alpha (e_1 + e_2),
              q_Mi'' + gamma q_Mi' = beta R_i(t) e_i(t - tau),       e_i = q_T - q_Mi

Initial condition: bases at rest at 0, tip at rest at ``amplitude``, so every
balancing error starts at ``amplitude`` (m) with the constant history
e_i(t) = amplitude for t in [-tau, 0] (:func:`initial_positions`).

:func:`plan_run` checks a run's request and holds what it records
(:class:`RecordedRun`): the CPU kernel here, the warp kernel of
:mod:`reduced.gpu` and the exact twin of :mod:`reduced.twin` share it, with the
sample layout of :func:`record_fields`.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from cipcore.driver import run_blocks
from cipcore.models import get_model
from cipcore.noise import GainNoise, make_noise
from cipcore.params import STEPPERS, BalanceParams, check_choice, whole_steps
from cipcore.scenario import Execution, Recording, Scenario
from cipcore.schema import (
    Trajectory,
    check_amplitude,
    check_duration,
    plan_recording,
)

from ._kernels import advance_positions


def n_controllers(model: str) -> int:
    """1 for the single model, 2 for the coupled one."""
    return get_model(model).n_controllers


def simulate(
    scenario: Scenario,
    *,
    stepper: str = "semi-implicit",
    noise: GainNoise | None = None,
    recording: Recording = Recording(),
    execution: Execution = Execution(),
) -> Trajectory:
    """Simulate the reduced model and record its time series.

    Parameters
    ----------
    scenario : the model ("single" or "coupled"), the gains, damping, noise, delay
        and time step, the duration (s, a whole number of steps), the number of
        independent noise realisations, the root seed of the noise (ignored when
        ``noise`` is given) and the initial balancing error (m, see the module
        docstring).
    stepper : "semi-implicit" (MuJoCo ``Euler``) or "explicit" (Euler–Maruyama).
    noise : a :class:`GainNoise` to consume (e.g. shared with another engine);
        it must be at position 0.
    recording : every ``decimate``-th step of the ``fields`` (names from
        :data:`cipcore.schema.COMMON_FIELDS`, default all), as ``dtype``; a recording
        beyond ``max_bytes`` is refused.
    execution : worker threads (default: all cores; results do not depend on it)
        and a progress bar.

    Returns
    -------
    Trajectory with the requested fields shaped (R, S, C), S = ceil(steps / decimate).
    """
    params = scenario.params
    check_choice("stepper", stepper, STEPPERS)
    run = plan_run(scenario, recording, noise, params.dt)
    d = params.delay_steps
    state, hist = initial_positions(run.noise.n_realizations, run.nc, d, run.amplitude)
    semi = stepper == "semi-implicit"

    def advance(block: slice, xi: np.ndarray, n0: int, nrec: int) -> np.ndarray:
        rec = np.empty((xi.shape[0], nrec, run.nc, 4))
        # the ring-buffer slot of step n0 - d is n0 mod d in every realisation
        advance_positions(
            xi, state[block], hist[block], n0 % d, params.law, semi, n0, run.decimate, rec,
        )  # fmt: skip
        return rec

    run.run(advance, threads=execution.threads, progress=execution.progress and "reduced")
    attrs = run.attrs("reduced", stepper, params, final_state=final_state(state))
    return run.trajectory(params.dt, attrs)


def initial_positions(
    n_realizations: int, nc: int, d: int, amplitude: float
) -> tuple[np.ndarray, np.ndarray]:
    """The reduced models' initial condition (module docstring) for the positions kernels.

    Returns
    -------
    state : (R, 2 + 2C) [q_T, v_T, q_M1, v_M1, ...]: the tip at rest at ``amplitude``
        (m), the bases at rest at 0.
    hist : (R, C, d) the delay rings, every balancing error's history at ``amplitude``.
    """
    state = np.zeros((n_realizations, 2 + 2 * nc))
    state[:, 0] = amplitude
    return state, np.full((n_realizations, nc, d), amplitude)


def final_state(state: np.ndarray) -> list | None:
    """A kernel's final state for a trajectory's attrs; None beyond 4096 numbers."""
    return state.tolist() if state.size <= 4096 else None


def sample_rows(n0: int, n: int, every: int) -> tuple[int, int]:
    """The rows [j0, j1) of a whole run's samples that steps n0 .. n0 + n - 1 record (a sample
    before every step whose index is a multiple of ``every``: :mod:`cipcore.control_kernel`)."""
    return -(-n0 // every), -(-(n0 + n) // every)


#: ``advance(block, xi, n0, nrec)``: advance the realisations ``block`` over the draws
#: ``xi`` (len(block), n, C) from global step ``n0``; return their ``nrec`` samples
#: (len(block), nrec, C, 4) [tip pos, tip vel, base pos, base vel] (:func:`record_fields`).
Advance = Callable[[slice, np.ndarray, int, int], np.ndarray]


@dataclass(frozen=True)
class RecordedRun:
    """A checked run of a reduced-family kernel and the arrays its samples go to.

    Attributes
    ----------
    model : "single" or "coupled";  nc : its controllers (1 or 2).
    duration : simulated time (s), n_steps : its whole number of steps.
    amplitude : the initial balancing error (m).
    noise : the draws (:class:`cipcore.noise.GainNoise`), at position 0.
    decimate : a sample every ``decimate`` steps;  n_samples : S = ceil(steps / decimate).
    out : the recorded fields, each (R, S, C) in the recording's dtype.
    """

    model: str
    nc: int
    duration: float
    n_steps: int
    amplitude: float
    noise: GainNoise
    decimate: int
    n_samples: int
    out: dict[str, np.ndarray]

    def run(
        self,
        advance: Advance,
        *,
        threads: int | None,
        progress: bool | str = False,
        chunk_steps: int | None = None,
    ) -> None:
        """Every chunk of draws through ``advance`` (:data:`Advance`), its samples stored in
        :attr:`out`; ``threads``, ``progress``, ``chunk_steps`` as :func:`run_blocks`'."""

        def work(block: slice, xi: np.ndarray, n0: int) -> None:
            j0, j1 = sample_rows(n0, xi.shape[1], self.decimate)
            _store(self.out, advance(block, xi, n0, j1 - j0), block, j0, j1)

        run_blocks(self.noise, self.n_steps, work, threads=threads, chunk_steps=chunk_steps,
                   progress=progress)  # fmt: skip

    def attrs(
        self, engine: str, stepper: str, params: BalanceParams, **extra: Any
    ) -> dict[str, Any]:
        """A trajectory's attrs: the engine, the run and the parameters (``params.as_dict()``),
        then ``extra`` in order."""
        return {
            "engine": engine,
            "model": self.model,
            "stepper": stepper,
            "seed": self.noise.seed,
            "first_realization": self.noise.first_realization,
            "amplitude": self.amplitude,
            "duration": self.duration,
            "decimate": int(self.decimate),
            **params.as_dict(),
            **extra,
        }

    def trajectory(self, dt: float, attrs: dict[str, Any]) -> Trajectory:
        """The recorded samples as a Trajectory, sample j at time j * decimate * dt (s)."""
        return Trajectory(time=np.arange(self.n_samples) * (dt * self.decimate), data=self.out,
                          attrs=attrs)  # fmt: skip


def plan_run(
    scenario: Scenario, recording: Recording, noise: GainNoise | None, dt: float
) -> RecordedRun:
    """Check a run of ``scenario`` stepped at ``dt`` (s) and allocate its recording.

    The duration must be a whole number of steps, the amplitude finite, ``noise`` (or
    the scenario's seed and realisations) gives the draws, ``recording`` the fields,
    their dtype and the decimation (refused beyond its ``max_bytes``).
    """
    nc = n_controllers(scenario.model)
    duration = check_duration(scenario.duration)
    n_steps = whole_steps("duration", duration, dt)
    amplitude = check_amplitude(scenario.amplitude)
    noise = make_noise(noise, scenario.seed, scenario.realizations, nc)
    nreal = noise.n_realizations
    n_samples, fields = plan_recording(n_steps, nreal, nc, recording)
    out = {f: np.empty((nreal, n_samples, nc), dtype=recording.dtype) for f in fields}
    return RecordedRun(scenario.model, nc, duration, n_steps, amplitude, noise,
                       recording.decimate, n_samples, out)  # fmt: skip


def record_fields(rec: np.ndarray) -> dict[str, np.ndarray]:
    """Every common schema field from kernel samples rec (..., 4) = [tip pos, tip vel,
    base pos, base vel] (m, m/s): positions, velocities and the balancing error e = x_T - x_M."""
    return {
        "tip_position": rec[..., 0],
        "tip_velocity": rec[..., 1],
        "base_position": rec[..., 2],
        "base_velocity": rec[..., 3],
        "balancing_error": rec[..., 0] - rec[..., 2],
        "balancing_error_velocity": rec[..., 1] - rec[..., 3],
    }


def _store(out: dict[str, np.ndarray], rec: np.ndarray, block: slice, j0: int, j1: int) -> None:
    """Copy recorded samples [tip pos, tip vel, base pos, base vel] into the schema's fields."""
    cols = {"tip_position": 0, "tip_velocity": 1, "base_position": 2, "base_velocity": 3}
    for name, arr in out.items():
        if name in cols:
            arr[block, j0:j1] = rec[..., cols[name]]
        elif name == "balancing_error":
            arr[block, j0:j1] = rec[..., 0] - rec[..., 2]
        elif name == "balancing_error_velocity":
            arr[block, j0:j1] = rec[..., 1] - rec[..., 3]
