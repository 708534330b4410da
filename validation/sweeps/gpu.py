"""GPU sweeps: every grid point x realisation of a study as one batch of MuJoCo Warp worlds.

World ``w`` is realisation ``w // P`` of point ``w % P`` (P points), so that the
points' differing model fields (rod length, masses, constraint settings) become
MuJoCo Warp per-world model fields (:func:`cip.engines.warp_batch.batched_model`) and
their control settings per-world arrays of the device control.  Each point
keeps its own seed (:func:`validation.sweep.point_seed`) and realisation ``r``
of it draws from ``GainNoise(seed, R, C)`` stream ``r``, exactly as the CPU
sweep does, so the same study means the same draws.  The per-point results have
the layout of :func:`validation.sweep.evaluate_point` and are saved and
assembled by the same :class:`validation.sweep.Store`, so resume rules and the
dataset are unchanged.

Limits: all points share the time step, duration and model structure
(integrator included); ``lambda1`` is not computed here (Benettin
renormalisation runs through the CPU driver: use the mujoco engine).  Records
are kept in float32 (the engine's precision) on the host: about
W x S x C x 3 x 4 bytes (64 points x 1024 realisations x 30 s at decimate 5: 9.4 GB).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from cipcore.models import get_model
from cipcore.noise import GainNoise
from cipcore.params import ParameterError, whole_steps
from cipcore.schema import Trajectory
from validation.sweeps.evaluate import nan_to_none, trajectory_metrics
from validation.sweeps.mapping import point_params
from validation.sweeps.study import Study, point_seed

GPU_METRICS = ("rms", "max_angle", "agreement", "tau_hat", "slopes")


def packed_trajectories(
    study: Study, points: list[dict[str, Any]], device: str | None = None
) -> list[Trajectory]:
    """One Trajectory per point (fields balancing_error, tip_velocity, base_velocity, angle;
    attrs max_abs_angle, diverged, seed) from one packed batch on the device."""
    from cip.engines.warp import point_control
    from cip.engines.warp_batch import WarpBatch
    from cip.model import build
    from cipcore.gpu import warp_device

    settings = [point_params(study, p) for p in points]
    dts = {s[0].dt for s in settings}
    if len(dts) > 1:
        raise ParameterError("dt must be the same for every point of a GPU sweep")
    dt = dts.pop()
    nc = get_model(study.model).n_controllers
    P, R, every = len(points), study.realizations, study.decimate
    models = [build(study.model, phys) for _, phys, _ in settings]
    controls = [point_control(par, phys, amp) for par, phys, amp in settings]
    chunk = every * max(1, -(-100 // every))
    try:
        batch = WarpBatch(models, controls, R, nc, device or warp_device(), max_chunk=chunk,
                          every=every)  # fmt: skip
    except ValueError as exc:
        raise ParameterError(f"these points cannot share one GPU batch: {exc}") from None
    n_steps = whole_steps("duration", study.duration, dt)
    n_samples = -(-n_steps // every)
    seeds = [point_seed(study, p) for p in points]
    noises = [GainNoise(s, R, nc) for s in seeds]
    names = ("balancing_error", "tip_velocity", "base_velocity", "angle")
    out = {f: np.full((P, R, n_samples, nc), np.nan, dtype=np.float32) for f in names}
    length = np.array([c.length for c in controls])[np.arange(batch.W) % P]
    stop = np.full(P, n_steps)
    xi = np.empty((batch.W, chunk, nc))
    for n0 in range(0, n_steps, chunk):
        n = min(chunk, n_steps - n0)
        for p, noise in enumerate(noises):
            xi[p::P, :n] = noise.next_chunk(n)
        vals = batch.fields(batch.advance(xi[:, :n]), length)
        j0 = n0 // every
        for f in names:
            v = vals[f].reshape(R, P, -1, nc).swapaxes(0, 1)
            live = stop > n0
            out[f][live, :, j0 : j0 + v.shape[2]] = v[live]
        bad = ~np.isfinite(batch.max_abs_angle()).reshape(R, P).all(axis=0)
        stop = np.where(bad & (stop == n_steps), n0 + n, stop)
        if (stop < n_steps).all():
            break
    max_angle = batch.max_abs_angle().reshape(R, P).T
    trs = []
    for p in range(P):
        k = -(-int(stop[p]) // every)
        data = {f: out[f][p, :, :k] for f in names}
        attrs = {"seed": seeds[p], "max_abs_angle": max_angle[p].tolist(),
                 "diverged": None if stop[p] == n_steps else {"time": float(stop[p] * dt)},
                 "engine": study.engine, "model": study.model, "dt": dt, "decimate": every,
                 "first_realization": 0}  # fmt: skip
        trs.append(Trajectory(time=np.arange(k) * dt * every, data=data, attrs=attrs))
    return trs


def evaluate_points(
    study_dict: dict, points: list[dict[str, Any]], device: str | None = None
) -> list[dict[str, Any]]:
    """The results of :func:`validation.sweep.evaluate_point` for many points in one batch.

    The metrics come from the same code as the CPU sweep's
    (:func:`validation.sweeps.evaluate.trajectory_metrics`), on the packed
    trajectories widened to float64 (no metric reads float32).
    """
    study = Study(**study_dict)
    if "lambda1" in study.metrics:
        raise ParameterError("metrics: lambda1 is not computed by the GPU sweep (use mujoco)")
    results = []
    for point, tr in zip(points, packed_trajectories(study, points, device), strict=True):
        params, _, amplitude = point_params(study, point)
        tr.data = {k: np.asarray(v, dtype=np.float64) for k, v in tr.data.items()}
        out: dict[str, Any] = {"seed": tr.attrs["seed"]}
        out.update(trajectory_metrics(study, params, amplitude, tr.attrs["seed"], tr))
        results.append({k: nan_to_none(v) for k, v in out.items()})
    return results
