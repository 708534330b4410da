"""Time series of the MuJoCo CIP under delayed random-gain (or PD) control.

Same call and output schema as :func:`reduced.simulate.simulate`, plus the
pendulum angles; the same seed draws the same noise as the reduced model.
Initial condition: carts at rest at their reference positions, every pendulum
at rest at the angle theta_0 = arcsin(amplitude / L), so the balancing error
starts at ``amplitude`` (m) with the constant history e(t) = amplitude, t < 0.

Every run records the largest |theta| of each realisation and flags those that
left the small-angle regime (|theta| > :func:`cip.model.small_angle_limit`,
about 0.077 rad, where sin(theta) departs from theta by 0.1 %).  A run whose
state turns non-finite or that raises a MuJoCo warning stops the run at the
end of that chunk: every realisation returns its samples up to there (the
same, whatever the thread timing), and ``attrs["diverged"]`` says which
realisation, when and why.
"""

from __future__ import annotations

import warnings

import numpy as np

from cip.model import CIPParams, small_angle_limit
from cip.runner import CIPRunner, Controller, RigidBody
from cipcore.driver import realization_blocks, run_blocks
from cipcore.models import get_model
from cipcore.noise import ArrayNoise, GainNoise, make_noise
from cipcore.params import whole_steps
from cipcore.scenario import Execution, Recording, Scenario
from cipcore.schema import (
    UNITS,
    Trajectory,
    check_amplitude,
    check_duration,
    plan_recording,
)

FULL_FIELDS = tuple(UNITS)


class DivergenceWarning(RuntimeWarning):
    """A MuJoCo run stopped early; the trajectory holds what was computed."""


def simulate_full(
    scenario: Scenario,
    *,
    body: RigidBody = RigidBody(),
    controller: Controller | None = None,
    noise: GainNoise | ArrayNoise | None = None,
    recording: Recording = Recording(),
    execution: Execution = Execution(),
) -> Trajectory:
    """Simulate the full CIP in MuJoCo (see the module docstring).

    ``scenario``, ``noise``, ``recording`` and ``execution`` as
    :func:`reduced.simulate.simulate` (the fields: :data:`FULL_FIELDS`, default all);
    ``body`` says which rigid body is stepped, with what (:class:`cip.runner.RigidBody`:
    the physical parameters, the backend, the engine's name, a compiled model file);
    ``controller`` replaces the paper's delayed random-gain feedback (e.g. PD).

    The function is long because the chunk callback (recording, the small-angle watch, the
    divergence stop) shares the run's arrays by closure.
    """
    model, params, amplitude = scenario.model, scenario.params, scenario.amplitude
    decimate, threads, mj_model, backend = (
        recording.decimate,
        execution.threads,
        body.mj_model,
        body.backend,
    )
    nc = get_model(model).n_controllers
    duration = check_duration(scenario.duration)
    n_steps = whole_steps("duration", duration, params.dt)
    amplitude = check_amplitude(amplitude)
    physical = body.physical or CIPParams.from_reduced(params)
    noise = make_noise(noise, scenario.seed, scenario.realizations, nc)
    nreal = noise.n_realizations
    n_samples, fields = plan_recording(n_steps, nreal, nc, recording, allowed=FULL_FIELDS)
    out = {f: np.empty((nreal, n_samples, nc), dtype=recording.dtype) for f in fields}
    max_angle = np.zeros(nreal)
    recorded = np.zeros(nreal, dtype=int)
    # each block's runner is built here, in this thread, before the driver's threads
    # start: a backend may fork worker processes (cip.workers), never beside running threads
    runners = {
        block.start: CIPRunner(
            model, params, physical, block.stop - block.start, amplitude,
            controller=controller, threads=1, backend=backend, mj_model=mj_model,
        )
        for block in realization_blocks(nreal, threads)
    }  # fmt: skip
    diverged: list[dict] = []
    stop = [n_steps]  # end of the earliest diverging chunk: every block runs up to it

    def work(block: slice, xi: np.ndarray, step: int) -> bool:
        if step >= stop[0]:
            return False  # a realisation diverged before this chunk: stop here
        runner = runners[block.start]
        n = xi.shape[1]
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
                out[f][block, j0 : j0 + take.size] = vals[f]
            recorded[block] = j0 + take.size
        ang = np.abs(states[..., runner.i_th])
        ang = np.where(np.isfinite(ang), ang, np.inf).max(axis=(1, 2))
        max_angle[block] = np.maximum(max_angle[block], ang)
        finite = np.isfinite(states).all(axis=(1, 2))
        nwarn = runner.warnings()
        if finite.all() and not nwarn:
            return True
        r = int(np.argmin(finite)) if not finite.all() else 0
        diverged.append({
            "realization": block.start + r + noise.first_realization,
            "time_window": [step * params.dt, (step + n) * params.dt],
            "reason": "non-finite state" if not finite.all() else f"{nwarn} MuJoCo warning(s)",
        })  # fmt: skip
        end = step + n
        if not finite.all():
            # the first step whose state is non-finite, in any realisation: the samples
            # before it (each the state before its step) are all finite, those after are not
            bad = int(np.argmax(~np.isfinite(states).all(axis=(0, 2))))
            end = step + bad + 1
        stop[0] = min(stop[0], end)
        return False

    run_blocks(noise, n_steps, work, threads=threads, chunk_steps=params.delay_steps,
               progress=execution.progress and "mujoco")  # fmt: skip
    first = min(diverged, key=lambda d: d["time_window"][0]) if diverged else None
    # every realisation has its samples up to the stop, whatever the thread timing
    n_rec = -(-stop[0] // decimate) if first else n_samples
    if first:
        out = {f: a[:, :n_rec] for f, a in out.items()}
        warnings.warn(
            f"{body.name} run stopped: {first['reason']} in realisation {first['realization']} "
            f"between t = {first['time_window'][0]:.4g} and {first['time_window'][1]:.4g} s; "
            f"returning the {n_rec} samples computed before it",
            DivergenceWarning,
            stacklevel=2,
        )
    limit = small_angle_limit()
    attrs = {
        "engine": body.name,
        "model": model,
        "stepper": physical.integrator,
        "seed": noise.seed,
        "first_realization": noise.first_realization,
        "amplitude": amplitude,
        "duration": duration,
        "decimate": int(decimate),
        **params.as_dict(),
        "physical": physical.as_dict(),
        "controller": (controller or Controller()).kind,
        "max_abs_angle": max_angle.tolist(),
        "small_angle_limit": limit,
        "left_small_angle": (max_angle > limit).tolist(),
        "diverged": first,
    }
    time = np.arange(n_rec) * (params.dt * decimate)
    return Trajectory(time=time, data=out, attrs=attrs)
