"""The reduced models on a GPU: one warp thread per realisation, float64.

The same discrete map as :func:`reduced._kernels.advance_positions` (paper eqs.
(3), (5); semi-implicit or explicit Euler, a d-slot delay ring
per controller, R_{i,n} = 1 + nu xi_{i,n} / sqrt(dt)), written as a warp kernel.
The draws xi come from :class:`cipcore.noise.GainNoise` on the host (one PCG64
stream per realisation) and are uploaded once per chunk, so the noise is the
same as the CPU kernel's for the same seed and the same for any batch split;
on warp's CPU device the trajectories equal the numba kernel's to rounding.

Why warp and not CuPy or numba-cuda: numba-cuda failed to compile against numpy
2.5 on the GPU image; CuPy raw kernels work there but cannot run without a CUDA
device, whereas a warp kernel also compiles for warp's CPU device, so the very
kernel that runs on the GPU is tested in CI-like runs against the numba kernel
(and ``mujoco-warp`` already brings warp).

Where it runs: see :mod:`cipcore.gpu` (a CUDA device, or ``CIPVAL_WARP_DEVICE=cpu``).
The largest Lyapunov exponent is computed by the CPU kernel
(:func:`reduced.lyapunov.lyapunov`, the same draws); only trajectories run on the device.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from cipcore.engine import Capabilities
from cipcore.gpu import declared_device, warp_device, warp_unavailable
from cipcore.models import BalanceModel
from cipcore.noise import GainNoise
from cipcore.params import STEPPERS, BalanceParams, check_choice
from cipcore.scenario import Execution, Recording, Scenario
from cipcore.schema import Trajectory

from .engine import ReducedEngine
from .simulate import final_state, initial_positions, plan_run, record_fields, sample_rows

#: Steps per uploaded chunk of draws (R * 4096 * C * 8 bytes on the device).
GPU_CHUNK_STEPS = 4096

_KERNEL: dict[str, Any] = {}


def _kernel():
    """The warp kernel, built on first use (warp is an optional dependency).

    The delay ring, the recording rule (:mod:`cipcore.control_kernel`), the Euler
    step and a balancer's sample (:mod:`reduced._steps`) are the numba kernels'
    own Python functions, compiled by warp (``wp.func``); the law is
    :mod:`cipcore.control_warp`'s (a typed literal), tested bit-equal to numba's.
    """
    if "k" in _KERNEL:
        return _KERNEL["k"]
    import warp as wp

    from cipcore.control_kernel import first_sample, ring_exchange, ring_next, sample_slot
    from cipcore.control_warp import delayed_random_gain

    from ._steps import euler_step, record_balancer

    wp.config.quiet = True
    wp.init()
    f64 = wp.float64
    first, slot, exchange, next_slot, step, record = (
        wp.func(f.py_func)
        for f in (first_sample, sample_slot, ring_exchange, ring_next, euler_step, record_balancer)
    )

    @wp.kernel
    def advance_positions(
        xi: wp.array3d(dtype=f64),
        state: wp.array2d(dtype=f64),
        hist: wp.array3d(dtype=f64),
        pos: int,
        alpha: f64,
        beta: f64,
        gamma: f64,
        noise_scale: f64,
        dt: f64,
        semi_implicit: int,
        n0: int,
        every: int,
        rec: wp.array4d(dtype=f64),
    ):
        """One realisation per thread: see reduced._kernels.advance_positions."""
        r = wp.tid()
        n = xi.shape[1]
        nc = xi.shape[2]
        rec_start = first(n0, every)
        q_t = state[r, 0]
        v_t = state[r, 1]
        p = pos
        for k in range(n):
            j = slot(n0 + k, every, rec_start, rec.shape[1])
            if j >= 0:
                for i in range(nc):
                    record(rec, r, j, i, q_t, v_t, state[r, 2 + 2 * i], state[r, 3 + 2 * i])
            esum = f64(0.0)
            for i in range(nc):
                q_m = state[r, 2 + 2 * i]
                v_m = state[r, 3 + 2 * i]
                e = q_t - q_m
                esum = esum + e
                u = delayed_random_gain(beta, noise_scale, xi[r, k, i], exchange(hist[r, i], p, e))
                q_m, v_m = step(q_m, v_m, -gamma * v_m + u, dt, semi_implicit)
                state[r, 2 + 2 * i] = q_m
                state[r, 3 + 2 * i] = v_m
            q_t, v_t = step(q_t, v_t, -gamma * v_t + alpha * esum / f64(nc), dt, semi_implicit)
            p = next_slot(p, hist.shape[2])
        state[r, 0] = q_t
        state[r, 1] = v_t

    _KERNEL["k"] = advance_positions
    _KERNEL["wp"] = wp
    return advance_positions


class DeviceReduced:
    """State, delay rings and draws of R realisations resident on a warp device.

    Initial condition as :func:`reduced.simulate.simulate`: bases at rest at 0,
    tip at rest at ``amplitude`` (m), constant error history.
    """

    def __init__(
        self,
        nc: int,
        params: BalanceParams,
        n_realizations: int,
        amplitude: float,
        *,
        device: str | None = None,
        max_chunk: int = GPU_CHUNK_STEPS,
        semi_implicit: bool = True,
    ) -> None:
        self.kernel = _kernel()
        wp = _KERNEL["wp"]
        self.wp, self.device = wp, device or warp_device()
        self.params, self.nc, self.R = params, nc, n_realizations
        self.d = params.delay_steps
        self.semi = int(semi_implicit)
        state, hist = initial_positions(n_realizations, nc, self.d, amplitude)
        with wp.ScopedDevice(self.device):
            self.state = wp.array(state, dtype=wp.float64)
            self.hist = wp.array(hist, dtype=wp.float64)
            self.xi = wp.zeros((n_realizations, max_chunk, nc), dtype=wp.float64)
        self.max_chunk = max_chunk
        self.step = 0
        self._rec: dict[int, Any] = {}

    def advance(self, xi: np.ndarray, every: int = 1, fetch: bool = True) -> np.ndarray | None:
        """Advance by n = xi.shape[1] steps; return the samples (R, S, C, 4) recorded
        before every step whose global index is a multiple of ``every``
        ([tip pos, tip vel, base pos, base vel], m and m/s), or None (``fetch`` False)."""
        wp, p = self.wp, self.params
        n = xi.shape[1]
        if n > self.max_chunk:
            raise ValueError(f"advance at most {self.max_chunk} steps at a time, got {n}")
        n0 = self.step
        j0, j1 = sample_rows(n0, n, every)
        nrec = j1 - j0
        if nrec not in self._rec:
            self._rec[nrec] = wp.zeros((self.R, nrec, self.nc, 4), dtype=wp.float64,
                                       device=self.device)  # fmt: skip
        rec = self._rec[nrec]
        xi_dev = self.xi if n == self.max_chunk else self.xi[:, :n]
        if n == self.max_chunk:
            xi_dev.assign(np.ascontiguousarray(xi, dtype=np.float64))
        else:
            xi_dev = wp.array(np.ascontiguousarray(xi, dtype=np.float64), dtype=wp.float64,
                              device=self.device)  # fmt: skip
        wp.launch(
            self.kernel, self.R,
            inputs=[xi_dev, self.state, self.hist, n0 % self.d, p.alpha, p.beta, p.gamma,
                    p.noise_scale, p.dt, self.semi, n0, every, rec],
            device=self.device,
        )  # fmt: skip
        self.step += n
        return rec.numpy() if fetch else None

    def final_state(self) -> np.ndarray:
        return self.state.numpy()


def simulate_gpu(
    scenario: Scenario,
    *,
    stepper: str = "semi-implicit",
    noise: GainNoise | None = None,
    recording: Recording = Recording(),
    execution: Execution = Execution(),
    device: str | None = None,
) -> Trajectory:
    """:func:`reduced.simulate.simulate` with the kernel on a warp device (same arguments).

    ``execution.threads`` is accepted for the common interface and ignored: the
    whole batch is one launch per chunk.  The returned Trajectory equals the CPU
    kernel's.  ``device`` is the warp device (default: warp's).
    """
    params = scenario.params
    check_choice("stepper", stepper, STEPPERS)
    run = plan_run(scenario, recording, noise, params.dt)
    chunk = min(GPU_CHUNK_STEPS, run.n_steps)
    dev = DeviceReduced(run.nc, params, run.noise.n_realizations, run.amplitude, device=device,
                        max_chunk=chunk, semi_implicit=stepper == "semi-implicit")  # fmt: skip

    def advance(block: slice, xi: np.ndarray, n0: int, nrec: int) -> np.ndarray:
        return dev.advance(xi, every=run.decimate)  # one block: every realisation

    run.run(advance, threads=1, chunk_steps=chunk,
            progress=execution.progress and "reduced-gpu")  # fmt: skip
    attrs = run.attrs("reduced-gpu", stepper, params, device=dev.device,
                      final_state=final_state(dev.final_state()))  # fmt: skip
    return run.trajectory(params.dt, attrs)


class GpuChunks:
    """:class:`cipcore.engine.ChunkRunner` over :class:`DeviceReduced` (semi-implicit)."""

    def __init__(self, model: BalanceModel, params: BalanceParams, n: int, amplitude: float):
        self.dev = DeviceReduced(model.n_controllers, params, n, amplitude)
        self.n_realizations = n
        self.max_chunk = self.dev.max_chunk

    @property
    def step(self) -> int:
        return self.dev.step

    def advance(self, xi: np.ndarray) -> dict[str, np.ndarray]:
        rec = self.dev.advance(xi)
        return record_fields(rec)


class ReducedGpuEngine(ReducedEngine):
    """The reduced models with the trajectory kernel on a warp device (float64).

    Everything but the device kernel is the reference engine's; lambda1 is
    computed by the CPU kernel (module docstring): the same draws, float64.
    """

    name = "reduced-gpu"
    capabilities = Capabilities(
        precision="float64",
        device=declared_device(),
        kernels="warp",
        rigid_body=False,
        linearize=False,
        family="reference",
        trajectory_tolerance=1e-12,
    )
    notes = "the reduced model as a warp kernel, one thread per realisation"
    chunks = GpuChunks
    simulate_fn = staticmethod(simulate_gpu)

    def unavailable(self) -> str | None:
        return warp_unavailable(("warp",))


ENGINE = ReducedGpuEngine()
