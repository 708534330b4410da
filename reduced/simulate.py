"""Time series of the reduced balancing models (paper eqs. (3), (5)).

    single:   x_T'' + gamma x_T' = alpha e(t),         x_M'' + gamma x_M' = beta R(t) e(t - tau)
    coupled:  2 q_T'' + 2 gamma q_T' = alpha (e_1 + e_2),
              q_Mi'' + gamma q_Mi' = beta R_i(t) e_i(t - tau),       e_i = q_T - q_Mi

Initial condition: bases at rest at 0, tip at rest at ``amplitude``, so every
balancing error starts at ``amplitude`` (m) with the constant history
e_i(t) = amplitude for t in [-tau, 0].
"""

from __future__ import annotations

import numpy as np

from cipcore.driver import run_blocks
from cipcore.models import get_model
from cipcore.noise import GainNoise, make_noise
from cipcore.params import (
    STEPPERS,
    check_choice,
    whole_steps,
)
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
    model, params = scenario.model, scenario.params
    decimate = recording.decimate
    nc = n_controllers(model)
    check_choice("stepper", stepper, STEPPERS)
    duration = check_duration(scenario.duration)
    n_steps = whole_steps("duration", duration, params.dt)
    amplitude = check_amplitude(scenario.amplitude)
    noise = make_noise(noise, scenario.seed, scenario.realizations, nc)
    nreal = noise.n_realizations
    n_samples, fields = plan_recording(n_steps, nreal, nc, recording)

    d = params.delay_steps
    state = np.zeros((nreal, 2 + 2 * nc))
    state[:, 0] = amplitude
    hist = np.full((nreal, nc, d), amplitude)
    out = {f: np.empty((nreal, n_samples, nc), dtype=recording.dtype) for f in fields}
    semi = stepper == "semi-implicit"

    def work(block: slice, xi: np.ndarray, n0: int) -> None:
        n = xi.shape[1]
        j0 = -(-n0 // decimate)
        j1 = -(-(n0 + n) // decimate)
        rec = np.empty((xi.shape[0], j1 - j0, nc, 4))
        # the ring-buffer slot of step n0 - d is n0 mod d in every realisation
        advance_positions(
            xi, state[block], hist[block], n0 % d, params.alpha, params.beta,
            params.gamma, params.noise_scale, params.dt, semi, n0, decimate, rec,
        )  # fmt: skip
        _store(out, rec, block, j0, j1)

    run_blocks(noise, n_steps, work, threads=execution.threads,
               progress=execution.progress and "reduced")  # fmt: skip
    time = np.arange(n_samples) * (params.dt * decimate)
    attrs = {
        "engine": "reduced",
        "model": model,
        "stepper": stepper,
        "seed": noise.seed,
        "first_realization": noise.first_realization,
        "amplitude": amplitude,
        "duration": duration,
        "decimate": int(decimate),
        **params.as_dict(),
        "final_state": state.tolist() if nreal * state.shape[1] <= 4096 else None,
    }
    return Trajectory(time=time, data=out, attrs=attrs)


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
