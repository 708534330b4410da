"""MJX (MuJoCo XLA) as a registered engine: the same CIP model compiled by JAX.

The backend advances a whole delay chunk inside one compiled ``jax.lax.scan``
over :func:`mujoco.mjx.step`, vmapped over realisations, in float64
(``jax_enable_x64``) on whatever device JAX has (CPU here, GPU where there is
one).  The delayed random-gain control of the chunk is computed beforehand by
:class:`cip.runner.CIPRunner` (it depends only on states a delay old), exactly as
for MuJoCo on the CPU, so both engines see the same controls for the same seed.

Two MJX facts this module works around (measured with MJX 3.17 and MuJoCo 4.0):

* ``jax.lax.scan`` over ``mjx.step`` with the whole ``mjx.Data`` as the carry
  fails under ``jax_enable_x64``: the tendon-wrap fields (``ten_wrapadr``,
  ``ten_wrapnum``, ``wrap_obj``) come back int64 from an int32 carry.  The
  carry is therefore only what the next step needs: qpos, qvel and the
  constraint solver's warm start ``qacc_warmstart``.
* MJX silently ignores actuator and sensor ``delay`` attributes; the CIP model
  uses none (the delay lives in the runner's history buffer).

MJX raises no MuJoCo warnings: divergence is detected from non-finite states.

Its floor against the exact twin (``benchmarks/twin_floor.py --engines mjx``,
1e-6 m, 2 realisations x 10 s, seed 1): 1.1e-11 single (Euler, implicitfast,
RK4), but 1.0e-6 coupled with the rod's stretch 5 times off the twin's.  The
constraint solver stops at the model file's ``opt.tolerance`` (1e-8) before it
iterates: at small amplitudes the warm start already meets that absolute
criterion, whereas MuJoCo on the CPU always takes a Newton iteration (exact for
the one rod row).  With ``opt.tolerance = 0`` MJX matches MuJoCo to 1.7e-16 and
the twin to 1.4e-11 (1 s, seed 1).  The engine runs the file as written, so its
declared tolerances are that measured floor (a finding about MJX, not hidden).
"""

from __future__ import annotations

import contextlib
import hashlib
import io
from typing import Any

import mujoco
import numpy as np

from cipcore.engine import Capabilities

from .engines import RigidBodyEngine

_COMPILED: dict[str, Any] = {}


def _model_key(model: mujoco.MjModel) -> str:
    buf = np.empty(mujoco.mj_sizeModel(model), dtype=np.uint8)
    mujoco.mj_saveModel(model, None, buf)
    return hashlib.sha256(buf.tobytes()).hexdigest()


def _compiled_chunk(model: mujoco.MjModel):
    """jit(vmap(scan of mjx.step over a chunk)) for ``model``, built once per model."""
    key = _model_key(model)
    if key in _COMPILED:
        return _COMPILED[key]
    import jax

    jax.config.update("jax_enable_x64", True)
    import jax.numpy as jnp

    with contextlib.redirect_stdout(io.StringIO()):
        # mujoco.mjx prints "Failed to import warp" on stdout when warp is absent
        # (its optional warp path); keep stdout clean for --json output.
        from mujoco import mjx

    mx = mjx.put_model(model)
    d0 = mjx.make_data(mx)

    def chunk(qpos, qvel, warm, ctrl):
        def body(carry, u):
            q, v, w = carry
            d = mjx.step(mx, d0.replace(qpos=q, qvel=v, qacc_warmstart=w, ctrl=u))
            return (d.qpos, d.qvel, d.qacc_warmstart), (d.qpos, d.qvel)

        (_, _, w), (qs, vs) = jax.lax.scan(body, (qpos, qvel, warm), ctrl)
        return qs, vs, w

    fn = jax.jit(jax.vmap(chunk))
    _COMPILED[key] = (fn, jnp)
    return _COMPILED[key]


class MJXRollout:
    """:class:`cip.runner.RolloutBackend` running MJX (float64) over a delay chunk."""

    def __init__(self, model: mujoco.MjModel, n_realizations: int, threads: int) -> None:
        self.fn, self.jnp = _compiled_chunk(model)
        self.nq, self.nv, self.dt = model.nq, model.nv, float(model.opt.timestep)
        self.warm = np.zeros((n_realizations, model.nv))

    def __call__(self, state: np.ndarray, ctrl: np.ndarray, out: np.ndarray) -> None:
        nq, nv = self.nq, self.nv
        jnp = self.jnp
        qs, vs, warm = self.fn(
            jnp.asarray(state[:, 1 : 1 + nq]),
            jnp.asarray(state[:, 1 + nq : 1 + nq + nv]),
            jnp.asarray(self.warm),
            jnp.asarray(ctrl),
        )
        n = ctrl.shape[1]
        out[...] = state[:, None, :]
        out[:, :, 0] = state[:, None, 0] + self.dt * np.arange(1, n + 1)
        out[:, :, 1 : 1 + nq] = np.asarray(qs)
        out[:, :, 1 + nq : 1 + nq + nv] = np.asarray(vs)
        self.warm = np.asarray(warm)

    def warnings(self) -> int:
        """MJX keeps no warning counters: always 0 (non-finite states are still caught)."""
        return 0


ENGINE = RigidBodyEngine(
    name="mjx",
    capabilities=Capabilities(
        precision="float64",
        device="cpu",
        rigid_body=True,
        linearize=False,
        family="MuJoCo (XLA)",
        trajectory_tolerance=1e-2,
        integrator="Euler",
        rod="soft",
        twin="the model file's terms, its soft rod (solref/solimp) and its integrator "
        "(Euler, implicitfast or RK4) as MuJoCo defines them",
    ),
    backend=lambda: MJXRollout,
    integrators=("Euler", "implicitfast", "RK4"),
    # the single model's floor is MuJoCo's (1.1e-11); the coupled model's is the
    # solver-tolerance floor (module docstring): 1.0e-6 against the twin, the rod's
    # stretch 5.3 times off; tolerances about ten times those (MuJoCo's 1e-9 single)
    twin_tolerance={"single": 1e-9, "coupled": 1e-5},
    rod_tolerance=50.0,
    requires=("jax", "mujoco.mjx"),
    max_threads=1,
    notes="MuJoCo XLA: jit(vmap(scan(mjx.step))) over a delay chunk, float64",
)
