"""The paper's nonlinear stick, eq. (1) (Cabrera & Milton 2002), as a third reduced model.

    theta'' + gamma theta' - alpha sin(theta) + beta R(t) theta(t - tau) = sigma eta(t)

R(t) = 1 + nu xi(t) as in the linear models (paper section 2.1); sigma eta(t)
is an optional additive white-noise floor (rad/s^2 per sqrt(Hz); 0 in the
paper).  Its linearisation theta ~ Delta x is the single linear model
(eq. (2)), and unlike it the sine saturates: the stick can fall over
(theta -> pi) instead of growing without bound, which on-off intermittency
needs (bursts that return to the laminar state).

Noise: the random gain of realisation r uses the same stream as the linear
models (:class:`reduced.noise.GainNoise`, ``SeedSequence(seed,
spawn_key=(r,))``), so for |theta| << 1 and sigma = 0 the angle equals the
linear single model's balancing error under the same seed; the floor has its
own stream per realisation (``spawn_key=(r, 1)``).  Same seed, same draws for
any thread count or realisation split.
"""

from __future__ import annotations

import numpy as np

from cipcore.driver import run_blocks
from cipcore.noise import GainNoise
from cipcore.params import STEPPERS, ParameterError, check_choice, whole_steps
from cipcore.scenario import Execution, Recording, Scenario
from cipcore.schema import Trajectory, check_amplitude, check_duration, plan_recording

from ._nonlinear_kernel import advance_angle

#: Fields of the nonlinear stick: eq. (1) has one coordinate, theta; the paper
#: identifies it with the balancing error (theta ~ Delta x).
NONLINEAR_FIELDS: tuple[str, ...] = ("balancing_error", "balancing_error_velocity", "angle")

_FLOOR_KEY = 1


class _GainAndFloorNoise:
    """Draws (steps, 2) per realisation: [gain stream of GainNoise, floor stream]."""

    def __init__(self, seed: int, n_realizations: int, first_realization: int = 0) -> None:
        self.gain = GainNoise(seed, n_realizations, 1, first_realization)
        self.seed = self.gain.seed
        self.first_realization = self.gain.first_realization
        self.n_realizations = self.gain.n_realizations
        self.n_controllers = 2
        self.position = 0
        self._floor = [
            np.random.Generator(
                np.random.PCG64(
                    np.random.SeedSequence(seed, spawn_key=(first_realization + r, _FLOOR_KEY))
                )
            )
            for r in range(self.n_realizations)
        ]

    def fill(self, realization: int, out: np.ndarray) -> None:
        g = np.empty((out.shape[0], 1))
        self.gain.fill(realization, g)
        out[:, 0] = g[:, 0]
        out[:, 1] = self._floor[realization].standard_normal(out.shape[0])


def simulate_nonlinear(
    scenario: Scenario,
    *,
    noise_floor: float = 0.0,
    stepper: str = "semi-implicit",
    recording: Recording = Recording(),
    execution: Execution = Execution(),
    first_realization: int = 0,
) -> Trajectory:
    """Simulate eq. (1) and record theta (module docstring).

    Parameters
    ----------
    scenario : model "single" (eq. (1) is one stick); gains (1/s^2), damping (1/s),
        noise strength nu (s^1/2), delay and step (s); the simulated time in s (a
        whole number of steps); the independent noise realisations and their root
        seed; the amplitude: the initial angle in rad, with the constant history
        theta = amplitude on [-tau, 0] and theta' = 0 (as the linear models'
        initial balancing error).
    noise_floor : sigma >= 0, additive white noise on theta'' (rad s^-3/2).
    stepper : "semi-implicit" or "explicit", as in :func:`reduced.simulate`.
    recording, execution : as in :func:`reduced.simulate`; fields from
        :data:`NONLINEAR_FIELDS` ("balancing_error" and "angle" are theta).
    first_realization : index of the first realisation (splits a run without
        changing any draw).

    Returns
    -------
    Trajectory with the fields shaped (R, S, 1), attrs["model"] = "nonlinear".
    """
    params, decimate = scenario.params, recording.decimate
    if scenario.model != "single":
        raise ParameterError(f"model: the nonlinear stick is eq. (1), one stick: 'single', "
                             f"got {scenario.model!r}")  # fmt: skip
    check_choice("stepper", stepper, STEPPERS)
    duration = check_duration(scenario.duration)
    sigma = float(noise_floor)
    if not np.isfinite(sigma) or sigma < 0:
        raise ParameterError(f"noise_floor must be finite and >= 0, got {noise_floor!r}")
    n_steps = whole_steps("duration", duration, params.dt)
    amplitude = check_amplitude(scenario.amplitude)
    noise = _GainAndFloorNoise(scenario.seed, scenario.realizations, first_realization)
    nreal = noise.n_realizations
    n_samples, fields = plan_recording(n_steps, nreal, 1, recording, allowed=NONLINEAR_FIELDS)
    d = params.delay_steps
    state = np.zeros((nreal, 2))
    state[:, 0] = amplitude
    hist = np.full((nreal, d), amplitude)
    out = {f: np.empty((nreal, n_samples, 1), dtype=recording.dtype) for f in fields}
    semi = stepper == "semi-implicit"
    floor_scale = sigma / np.sqrt(params.dt)

    def work(block: slice, xi: np.ndarray, n0: int) -> None:
        n = xi.shape[1]
        j0 = -(-n0 // decimate)
        j1 = -(-(n0 + n) // decimate)
        rec = np.empty((xi.shape[0], j1 - j0, 2))
        advance_angle(
            xi, state[block], hist[block], n0 % d, params.law, floor_scale, semi, n0,
            decimate, rec,
        )  # fmt: skip
        for name, arr in out.items():
            arr[block, j0:j1, 0] = rec[..., 1 if name == "balancing_error_velocity" else 0]

    run_blocks(noise, n_steps, work, threads=execution.threads)
    attrs = {
        "engine": "reduced",
        "model": "nonlinear",
        "stepper": stepper,
        "seed": noise.seed,
        "first_realization": noise.first_realization,
        "amplitude": amplitude,
        "noise_floor": sigma,
        "duration": duration,
        "decimate": int(decimate),
        **params.as_dict(),
    }
    return Trajectory(time=np.arange(n_samples) * (params.dt * decimate), data=out, attrs=attrs)
