"""Time series of the MuJoCo CIP under delayed random-gain (or PD) control.

Same call and output schema as :func:`reduced.simulate.simulate`, plus the
pendulum angles; the same seed draws the same noise as the reduced model.
Initial condition: carts at rest at their reference positions, every pendulum
at rest at the angle theta_0 = arcsin(amplitude / L), so the balancing error
starts at ``amplitude`` (m) with the constant history e(t) = amplitude, t < 0.

Every run records the largest |theta| of each realisation and flags those that
left the small-angle regime (|theta| > :func:`cip.model.small_angle_limit`,
about 0.17 rad, where sin(theta) departs from theta by 0.5 %).  A run whose
state turns non-finite or that raises a MuJoCo warning stops at that chunk and
returns what it computed, with ``attrs["diverged"]`` saying which realisation,
when and why.
"""

from __future__ import annotations

import warnings

import numpy as np
from tqdm.auto import tqdm

from reduced.noise import ArrayNoise, GainNoise
from reduced.params import BalanceParams, check_choice, whole_steps
from reduced.schema import UNITS, Trajectory
from reduced.simulate import (
    DEFAULT_MAX_BYTES,
    _check_duration,
    _noise,
    check_amplitude,
    plan_recording,
)

from .model import CIPParams, small_angle_limit
from .runner import CIPRunner, Controller

FULL_FIELDS = tuple(UNITS)


class DivergenceWarning(RuntimeWarning):
    """A MuJoCo run stopped early; the trajectory holds what was computed."""


def simulate_full(
    model: str,
    params: BalanceParams,
    duration: float,
    n_realizations: int = 1,
    seed: int = 0,
    *,
    amplitude: float = 0.01,
    physical: CIPParams | None = None,
    controller: Controller | None = None,
    decimate: int = 1,
    fields: tuple[str, ...] = FULL_FIELDS,
    dtype: type | np.dtype = np.float64,
    noise: GainNoise | ArrayNoise | None = None,
    threads: int | None = None,
    max_bytes: int = DEFAULT_MAX_BYTES,
    progress: bool = False,
) -> Trajectory:
    """Simulate the full CIP in MuJoCo (see the module docstring).

    Parameters as :func:`reduced.simulate.simulate`; ``physical`` defaults to
    :meth:`CIPParams.from_reduced` of ``params`` (L = g/alpha, m/M = 1e-3).
    """
    check_choice("model", model, ("single", "coupled"))
    nc = 1 if model == "single" else 2
    duration = _check_duration(duration)
    n_steps = whole_steps("duration", duration, params.dt)
    amplitude = check_amplitude(amplitude)
    physical = physical or CIPParams.from_reduced(params)
    noise = _noise(noise, seed, n_realizations, nc)
    nreal = noise.n_realizations
    n_samples = plan_recording(
        n_steps, nreal, nc, decimate, tuple(fields), dtype, max_bytes, allowed=FULL_FIELDS
    )
    runner = CIPRunner(
        model, params, physical, nreal, amplitude, controller=controller, threads=threads
    )
    out = {f: np.empty((nreal, n_samples, nc), dtype=dtype) for f in fields}
    max_angle = np.abs(runner.fields(runner.state)["angle"]).max(axis=1)
    diverged = None
    bar = tqdm(total=n_steps * nreal, unit="step", unit_scale=True, disable=not progress,
               desc="mujoco", leave=False)  # fmt: skip
    step = 0
    recorded = 0
    try:
        while step < n_steps:
            n = min(runner.d, n_steps - step)
            xi = noise.next_chunk(n)
            before = runner.state
            states = runner.advance(xi)
            # samples at global steps step .. step+n-1 whose index is a multiple of decimate
            idx = np.arange(step, step + n)
            take = idx[idx % decimate == 0]
            if take.size:
                sel = np.concatenate([before[:, None], states[:, :-1]], axis=1)[:, take - step]
                vals = runner.fields(sel)
                j0 = take[0] // decimate
                for f in fields:
                    out[f][:, j0 : j0 + take.size] = vals[f]
                recorded = j0 + take.size
            ang = np.abs(states[..., runner.i_th])
            finite = np.isfinite(states).all(axis=(1, 2))
            max_angle = np.maximum(
                max_angle, np.where(np.isfinite(ang), ang, np.inf).max(axis=(1, 2))
            )
            step += n
            bar.update(n * nreal)
            nwarn = runner.warnings()
            if not finite.all() or nwarn:
                r = int(np.argmin(finite)) if not finite.all() else None
                diverged = {
                    "realization": None if r is None else r + noise.first_realization,
                    "time_window": [(step - n) * params.dt, step * params.dt],
                    "reason": "non-finite state" if r is not None else f"{nwarn} MuJoCo warning(s)",
                }
                break
    finally:
        bar.close()
    if diverged is not None:
        out = {f: a[:, :recorded] for f, a in out.items()}
        warnings.warn(
            f"MuJoCo run stopped: {diverged['reason']} in realisation {diverged['realization']} "
            f"between t = {diverged['time_window'][0]:.4g} and {diverged['time_window'][1]:.4g} s; "
            f"returning the {recorded} samples computed",
            DivergenceWarning,
            stacklevel=2,
        )
    limit = small_angle_limit()
    attrs = {
        "engine": "mujoco",
        "model": model,
        "stepper": physical.integrator,
        "seed": noise.seed,
        "first_realization": noise.first_realization,
        "amplitude": amplitude,
        "duration": duration,
        "decimate": int(decimate),
        **params.as_dict(),
        "physical": physical.as_dict(),
        "controller": runner.controller.kind,
        "max_abs_angle": max_angle.tolist(),
        "small_angle_limit": limit,
        "left_small_angle": (max_angle > limit).tolist(),
        "diverged": diverged,
    }
    time = np.arange(recorded if diverged else n_samples) * (params.dt * decimate)
    return Trajectory(time=time, data=out, attrs=attrs)
