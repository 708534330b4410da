"""MuJoCo Warp as a registered engine: a batch of float32 worlds on a GPU.

``mujoco-warp`` 4.0 (on NVIDIA ``warp-lang`` 1.19) loads the CIP's MJCF
unchanged (tendon equality, affine-bias actuators with site transmission and
refsite, Euler) and steps one world per realisation.  Everything it computes is
float32 (``Capabilities.precision``): single paths separate from float64 MuJoCo
at the Lyapunov rate, so it is validated on statistics as well as on short
trajectories.

Where it runs: a CUDA device when warp finds one.  Without one the engine is
unavailable, with the reason, unless ``CIPVAL_WARP_DEVICE=cpu`` opts into
warp's CPU device (the same kernels, slow; for tests and smoke runs); the
capabilities then say ``device="cpu"``.  First use compiles about 40 warp
modules (about a minute; cached on disk afterwards).

Two paths (see :mod:`cip.engines.warp_batch`):

* :meth:`WarpEngine.runner` (and the GPU benchmark and GPU sweeps) compute the
  delayed random-gain control on the device from a ring buffer of balancing
  errors, with the per-realisation draws uploaded once per chunk;
* ``simulate`` and ``lyapunov`` run the shared drivers
  (:func:`cip.simulate.simulate_full`, :func:`cip.lyapunov.lyapunov_full`, with
  their divergence stop, recording and Benettin renormalisation) with the
  control of each delay chunk computed on the host and uploaded once per chunk.

Both consume the same :class:`cipcore.noise.GainNoise` draws as every engine.

Where float32 stops being good enough (measured on warp's CPU device, same
kernels as on a GPU; 1 s, 2 realisations, seed 7, beta = 21.032, relative L2
distance of the balancing error to float64 MuJoCo under the same draws): the
single CIP stays at float32 rounding (1.8e-7, 3.0e-7, 3.6e-7 at amplitudes
1e-6, 1e-4, 1e-2 m), but the coupled CIP's rod constraint, a tendon length
compared with its reference in float32 (resolution about l * 6e-8 m), adds an
absolute error floor: 6.2e-3, 7.0e-5, 1.3e-6 at the same amplitudes, i.e.
relative error ~ 1/amplitude.  Below about 1e-5 m the rod constraint of this
engine is float32 noise at the 0.1 % level and more.
MuJoCo Warp keeps no MuJoCo warning counters; divergence is detected from
non-finite states.  Reductions are made deterministic
(``DeterminismType.ALL``), so reruns are bit-identical.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from cip.engines.rigid_body import RigidBodyEngine
from cip.model import CIPParams, build
from cipcore.engine import Capabilities
from cipcore.gpu import declared_device, warp_device, warp_unavailable
from cipcore.models import BalanceModel
from cipcore.params import BalanceParams, ParameterError


def unavailable_reason() -> str | None:
    """None when mujoco-warp can run here, else why not (one line)."""
    return warp_unavailable(("warp", "mujoco_warp"))


def device() -> str:
    """The warp device the engine runs on: "cuda:0" or "cpu"."""
    return warp_device()


def rollout_backend() -> type:
    """:class:`cip.engines.warp_batch.WarpRollout` bound to :func:`device`."""
    from cip.engines.warp_batch import WarpRollout

    return type("WarpRollout", (WarpRollout,), {"device": device()})


def point_control(params: BalanceParams, physical: CIPParams, amplitude: float):
    """The device control's :class:`cip.engines.warp_batch.PointControl` of one setting.

    gain M beta (kg/s^2), scale nu / sqrt(dt), L (m), d = tau/dt (steps), amplitude (m).
    """
    from cip.engines.warp_batch import PointControl

    L = physical.pendulum_length
    if not abs(amplitude) < L:
        raise ParameterError(
            f"amplitude must be an initial balancing error |e| < L = {L:.4g} m, got {amplitude!r}"
        )
    return PointControl(
        gain=physical.cart_mass * params.beta,
        scale=params.noise_scale,
        length=L,
        delay=params.delay_steps,
        amplitude=float(amplitude),
    )


class WarpChunks:
    """:class:`cipcore.engine.ChunkRunner` with the delayed random-gain control on the device."""

    def __init__(
        self,
        model: BalanceModel,
        params: BalanceParams,
        n_realizations: int,
        amplitude: float,
        physical: CIPParams,
        *,
        device: str | None = None,
    ) -> None:
        from cip.engines.warp_batch import WarpBatch

        if abs(physical.timestep - params.dt) > 1e-15:
            raise ParameterError(
                f"physical timestep {physical.timestep} differs from dt {params.dt}"
            )
        ctl = point_control(params, physical, amplitude)
        self.batch = WarpBatch(
            [build(model.name, physical)], [ctl], n_realizations, model.n_controllers,
            device or warp_device(), max_chunk=params.delay_steps, every=1,
        )  # fmt: skip
        self.length = np.full(n_realizations, ctl.length)
        self.n_realizations = n_realizations
        self.max_chunk = params.delay_steps

    @property
    def step(self) -> int:
        return self.batch.step

    def advance(self, xi: np.ndarray) -> dict[str, np.ndarray]:
        rec = self.batch.advance(xi)
        return self.batch.fields(rec, self.length)


class WarpEngine(RigidBodyEngine):
    """MuJoCo Warp: :meth:`runner` keeps the control on the device (see the module docstring)."""

    def make_runner(self, model: BalanceModel, params: BalanceParams, n_realizations: int,
                    amplitude: float, physical: CIPParams | None) -> WarpChunks:  # fmt: skip
        physical = physical or CIPParams.from_reduced(params)
        return WarpChunks(model, params, n_realizations, amplitude, physical)


def _capabilities() -> Capabilities:
    return Capabilities(
        precision="float32",
        device=declared_device(),
        kernels="warp",
        family="MuJoCo (Warp)",
        packs_points=True,
        # one set of launches for every world on a GPU; unmeasured on warp's CPU device
        batch=declared_device() != "cpu",
        twin="the model file's terms, soft rod and Euler in float64; the engine computes in "
        "float32, so its tolerance is its float32 floor",
    )


def _notes() -> str:
    return "MuJoCo Warp, float32, a batch of worlds; delay chunk as one CUDA graph"


ENGINE: Any = WarpEngine(
    name="mujoco-warp",
    capabilities=_capabilities(),
    backend=rollout_backend,
    probe=unavailable_reason,
    max_threads=1,
    notes=_notes(),
    # float32 floor against the twin (benchmarks/twin_floor.py --engines mujoco-warp,
    # warp's CPU device, 1e-6 m, 1 realisation x 2 s, seed 1): 9.1e-7 single, 6.7e-3
    # coupled (the rod's float32 resolution; 5.9e-5 at 1e-4 m); the rod's stretch is
    # float32 noise there (8e4 times the twin's).  Tolerances about ten times those
    # floors (not measured over the check's full 10 s)
    twin_tolerance={"single": 1e-5, "coupled": 5e-2},
    rod_tolerance=1e6,
)
