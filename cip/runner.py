"""Advance many realisations of the MuJoCo CIP under delayed feedback, tau at a time.

The control over step n is  F_i = M * beta * R_{i,n} * e_i(n - d),  d = tau/dt,
with the noise R_{i,n} at step n (not n - d) and e_i = L sin(theta_i), the bob's
x minus the cart's x.  Over the next d steps it depends only on states already
computed, so the controls of a whole chunk of d steps are known in advance:
one ``mujoco.rollout`` call advances every realisation d steps across threads
at the engine's own speed, and Python touches the delay buffer once per chunk
(measured: a Python step loop with the control computed each step costs about
56 us/step, the rollout chunk about 6 us/step for the coupled CIP).  Chunking
by d is exact: the rollout of a chunk starts from the last state of the
previous one.

MuJoCo's native actuator delay (``delay``/``nsample``) would delay ``ctrl``,
noise included (the noise would be applied at t - tau); the chunked rollout
keeps the noise at t and needs no callback.
"""

from __future__ import annotations

import copy
import os
from dataclasses import dataclass, field
from typing import Protocol

import mujoco
import numpy as np
from mujoco import rollout

from cip.mjstages import unused_stage_flags
from cip.mjtimer import timers_off
from cip.model import CIPParams, build
from cip.names import cart_joint, hinge_joint, motor
from cipcore.control_law import delayed_random_gain
from cipcore.models import get_model
from cipcore.params import BalanceParams, ParameterError

STATE_SPEC = mujoco.mjtState.mjSTATE_FULLPHYSICS


@dataclass
class Controller:
    """The control law on the carts.

    kind "delayed-random-gain":  F_i = M beta R_i(t) e_i(t - tau)  (paper eq. (5))
    kind "pd":                   F_i = M (kp e_i(t - tau) + kd e_i'(t - tau))
    (the PD-controlled CIP of the authors' earlier work, with the same delay;
    tau may be one step for an undelayed PD).
    """

    kind: str = "delayed-random-gain"
    kp: float = 0.0
    kd: float = 0.0

    def __post_init__(self) -> None:
        if self.kind not in ("delayed-random-gain", "pd"):
            raise ParameterError(f"controller must be delayed-random-gain or pd, got {self.kind!r}")


class RolloutBackend(Protocol):
    """Steps a batch of rigid-body states under given controls: the engine-specific part.

    ``backend(state, ctrl, out)`` advances every realisation from ``state``
    (R, nstate), an ``mjSTATE_FULLPHYSICS`` vector (time, qpos, qvel, ...), over
    n = ctrl.shape[1] steps, the control ``ctrl[:, k]`` (R, n, nu) held over step k,
    and writes the states after each step into ``out`` (R, n, nstate).

    A backend stepped in worker processes (:class:`cip.workers.ProcessBlocks`) may
    also have a static ``preload()`` that imports its engine's library: the parent
    runs it before forking the workers, which then inherit it.
    """

    def __init__(self, model: mujoco.MjModel, n_realizations: int, threads: int) -> None: ...

    def __call__(self, state: np.ndarray, ctrl: np.ndarray, out: np.ndarray) -> None: ...

    def warnings(self) -> int: ...


class MujocoRollout:
    """MuJoCo on the CPU: one ``mujoco.rollout`` call per chunk, across threads.

    The runner reads states only, so the rollout steps a copy of the model with its
    sensor stage disabled (sensors are outputs: the states are the same bit for bit;
    about 5-10 % of a coupled step), and with MuJoCo's profiling timers off
    (:mod:`cip.mjtimer`: outputs too; a sixth of a coupled step, a third of a single),
    and without the constraint stages the model cannot use (:mod:`cip.mjstages`: the
    same states bit for bit; 0.82 of a single step's time, 0.87 of a coupled one's).
    """

    #: switch off the pipeline stages the model cannot use (:mod:`cip.mjstages`)
    skip_unused_stages = True

    def __init__(self, model: mujoco.MjModel, n_realizations: int, threads: int) -> None:
        model = copy.copy(model)  # the caller's model keeps its sensors and its flags
        model.opt.disableflags |= mujoco.mjtDisableBit.mjDSBL_SENSOR
        if self.skip_unused_stages:
            model.opt.disableflags |= unused_stage_flags(model)
        self.models = [model] * n_realizations
        self.datas = [mujoco.MjData(model) for _ in range(threads)]
        self._sens: np.ndarray | None = None
        self.nsensordata = model.nsensordata
        # one thread pool for every call (mujoco.rollout.Rollout, MuJoCo >= 3.3.1), not
        # one started and joined per call as mujoco.rollout.rollout does: 55-325 us a
        # one-step call with 2 threads against 7-26 us with one, where the closed-loop
        # check steps one control interval a call.  A realisation's steps do not depend
        # on the thread that runs them.  The pool ends with this object.
        pool = getattr(rollout, "Rollout", None)
        self._rollout = (pool(nthread=threads if threads > 1 else 0).rollout
                         if pool is not None else rollout.rollout)  # fmt: skip

    def __call__(self, state: np.ndarray, ctrl: np.ndarray, out: np.ndarray) -> None:
        n = ctrl.shape[1]
        if self._sens is None or self._sens.shape[1] != n:
            self._sens = np.empty((len(self.models), n, self.nsensordata))
        with timers_off():  # no clock reads in the steps (cip.mjtimer)
            self._rollout(
                self.models, self.datas, state, ctrl, nstep=n,
                skip_checks=True, state=out, sensordata=self._sens,
            )  # fmt: skip

    def warnings(self) -> int:
        """Number of MuJoCo warnings (bad qacc, instability) raised in the worker data."""
        return sum(int(d.warning[w].number) for d in self.datas for w in range(len(d.warning)))


@dataclass(frozen=True)
class RigidBody:
    """Which rigid body a simulation steps, and with what.

    Attributes
    ----------
    physical : the rigid body's parameters (default: :meth:`CIPParams.from_reduced`
        of the scenario's parameters: L = g/alpha, m/M = 1e-3).
    backend : the stepper (default :class:`MujocoRollout`, MuJoCo on the CPU).
    name : the engine's name, recorded in the trajectory's ``attrs["engine"]``.
    mj_model : a compiled model file to run instead of :func:`cip.model.build`'s
        (``physical`` must then describe it, see :func:`cip.mjcf_params.read_mapping`).
    """

    physical: CIPParams | None = None
    backend: type[RolloutBackend] | None = None
    name: str = "mujoco"
    mj_model: object = field(default=None, compare=False)


def schema_fields(
    x: np.ndarray, v: np.ndarray, e: np.ndarray, edot: np.ndarray, angle: np.ndarray
) -> dict[str, np.ndarray]:
    """The shared schema's fields (:mod:`cipcore.schema`) of the rigid body, each (..., C):
    cart position x (m) and velocity v (m/s), balancing error e = L sin(theta) (m) and
    its rate e' = L cos(theta) theta' (m/s), the pendulum's angle theta (rad); the tip
    is at x + e."""
    return {
        "tip_position": x + e,
        "tip_velocity": v + edot,
        "base_position": x,
        "base_velocity": v,
        "balancing_error": e,
        "balancing_error_velocity": edot,
        "angle": angle,
    }


class CIPRunner:
    """State of R realisations of the single or coupled CIP and their delay buffers.

    Attributes
    ----------
    state : (R, nstate) mjSTATE_FULLPHYSICS states (time, qpos, qvel).
    e_hist, edot_hist : (R, d, C) balancing errors (m) and their rates (m/s)
        at steps n - d .. n - 1, n the next step.
    betas : (R,) each realisation's gain beta (1/s^2): ``params.beta`` unless the
        constructor's ``betas`` gives one per realisation (several gains in one batch).
    """

    def __init__(
        self,
        model: str,
        params: BalanceParams,
        physical: CIPParams,
        n_realizations: int,
        amplitude: float,
        *,
        controller: Controller | None = None,
        threads: int | None = None,
        backend: type[RolloutBackend] | None = None,
        mj_model: mujoco.MjModel | None = None,
        betas: np.ndarray | None = None,
    ) -> None:
        self.model_name = model
        self.params = params
        self.physical = physical
        self.controller = controller or Controller()
        self.nc = get_model(model).n_controllers
        if abs(physical.timestep - params.dt) > 1e-15:
            raise ParameterError(
                f"physical timestep {physical.timestep} differs from dt {params.dt}"
            )
        L = physical.pendulum_length
        if not abs(amplitude) < L:
            raise ParameterError(
                f"amplitude must be an initial balancing error |e| < L = {L:.4g} m, "
                f"got {amplitude!r}"
            )
        # a compiled model file (cip.mjcf_params) or the shipped file edited to ``physical``
        self.m = mj_model if mj_model is not None else build(model, physical)
        self.L = L
        self.d = params.delay_steps
        names = [
            mujoco.mj_id2name(self.m, mujoco.mjtObj.mjOBJ_JOINT, j) for j in range(self.m.njnt)
        ]
        self.nstate = mujoco.mj_stateSize(self.m, STATE_SPEC)
        qpos0 = 1  # time comes first in mjSTATE_FULLPHYSICS
        qvel0 = 1 + self.m.nq
        ix = [names.index(cart_joint(i + 1)) for i in range(self.nc)]
        it = [names.index(hinge_joint(i + 1)) for i in range(self.nc)]
        self.i_x = np.array([qpos0 + self.m.jnt_qposadr[j] for j in ix])
        self.i_th = np.array([qpos0 + self.m.jnt_qposadr[j] for j in it])
        self.i_vx = np.array([qvel0 + self.m.jnt_dofadr[j] for j in ix])
        self.i_om = np.array([qvel0 + self.m.jnt_dofadr[j] for j in it])
        self.i_u = np.array(
            [
                mujoco.mj_name2id(self.m, mujoco.mjtObj.mjOBJ_ACTUATOR, motor(i + 1))
                for i in range(self.nc)
            ]
        )
        self.threads = max(1, min(threads or os.cpu_count() or 1, n_realizations))
        self.n_realizations = n_realizations
        self.betas = np.full(n_realizations, params.beta)
        if betas is not None:
            b = np.ravel(betas).astype(float)
            if b.shape != (n_realizations,) or not np.all(np.isfinite(b) & (b >= 0)):
                raise ParameterError(f"betas must be {n_realizations} finite gains >= 0 "
                                     f"(1/s^2), got {b.tolist()}")  # fmt: skip
            self.betas = b
        self.backend = (backend or MujocoRollout)(self.m, n_realizations, self.threads)
        data = mujoco.MjData(self.m)
        theta0 = np.arcsin(amplitude / L)
        for j in it:
            data.qpos[self.m.jnt_qposadr[j]] = theta0
        mujoco.mj_forward(self.m, data)
        s0 = np.empty(self.nstate)
        mujoco.mj_getState(self.m, data, s0, STATE_SPEC)
        self.state = np.tile(s0, (n_realizations, 1))
        e0, edot0 = self.errors(self.state[:, None, :])
        self.e_hist = np.repeat(e0, self.d, axis=1)
        self.edot_hist = np.repeat(edot0, self.d, axis=1)
        self.step = 0
        self.controls = np.zeros((n_realizations, self.d, self.m.nu))

    # ------------------------------------------------------------------
    def errors(self, states: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Balancing error e = L sin(theta) (m) and its rate L cos(theta) theta' (m/s).

        ``states`` (..., nstate) -> two arrays (..., C).
        """
        th = states[..., self.i_th]
        return self.L * np.sin(th), self.L * np.cos(th) * states[..., self.i_om]

    def advance(self, xi: np.ndarray | None) -> np.ndarray:
        """Advance every realisation by n = xi.shape[1] <= d steps.

        ``xi`` (R, n, C) are the standard-normal draws of steps step .. step+n-1
        (ignored by the PD controller, which then needs n only: pass an
        array of zeros).  Returns the states *after* each step, (R, n, nstate).
        """
        n = xi.shape[1]
        if n > self.d:
            raise ValueError("advance at most tau at a time")
        p, M = self.params, self.physical.cart_mass
        ctrl = self.controls[:, :n]
        if self.controller.kind == "pd":
            c = self.controller
            u = M * (c.kp * self.e_hist[:, :n] + c.kd * self.edot_hist[:, :n])
        else:
            gain = M * self.betas[:, None, None]  # M beta per realisation (N/m)
            u = delayed_random_gain(gain, p.noise_scale, xi, self.e_hist[:, :n])
        ctrl[:, :, self.i_u] = u
        out = np.empty((self.n_realizations, n, self.nstate))
        self.backend(self.state, np.ascontiguousarray(ctrl), out)
        e, edot = self.errors(out)
        # e at steps step .. step+n-1 are: current state, then out[:, :n-1]
        e_cur, edot_cur = self.errors(self.state)
        new_e = np.concatenate([e_cur[:, None], e[:, : n - 1]], axis=1)
        new_edot = np.concatenate([edot_cur[:, None], edot[:, : n - 1]], axis=1)
        self.e_hist = np.concatenate([self.e_hist[:, n:], new_e], axis=1)
        self.edot_hist = np.concatenate([self.edot_hist[:, n:], new_edot], axis=1)
        self.state = out[:, -1].copy()
        self.step += n
        return out

    def warnings(self) -> int:
        """Number of engine warnings (bad qacc, instability) raised so far."""
        return self.backend.warnings()

    def fields(self, states: np.ndarray) -> dict[str, np.ndarray]:
        """The shared schema's fields from states (..., nstate) -> (..., C) each."""
        x = states[..., self.i_x]
        v = states[..., self.i_vx]
        e, edot = self.errors(states)
        return schema_fields(x, v, e, edot, states[..., self.i_th])
