"""Each engine's own stepping loop, timed on the model its cipval adapter builds.

``benchmarks/bench_engines.py --native`` prints, beside an adapter's throughput
(realisation-steps/s through ``engine.simulate``), the throughput of the engine's
own step call in a tight Python loop on the same model and the same number of
realisations, and their ratio.  Each loop here:

* gets the engine's objects from the adapter's own rollout backend, built as the
  adapter builds it (``engine.rollout()(mj_model, R, 1)`` inside a
  :class:`cip.runner.CIPRunner`, from the model ``engine.simulate`` steps:
  :func:`cip.model.build` of :meth:`cip.model.CIPParams.from_reduced`), so the
  engine steps the same bodies, rod, solver settings and time step;
* starts every realisation from the runner's start state (the amplitude's tilt);
* holds one control: the delayed law's value at the start, F = M beta e(0) on each
  cart (no noise, no delay buffer), with the model's dampers evaluated once at the
  start state and held as generalised forces (:func:`held_forces`) where the adapter
  applies them itself;
* times only the engine's step calls (setting states and forces, building clients,
  and compiling happen before the clock starts), recording nothing.

Where an adapter adds physics of its own in Python (the rigid rod's velocity
projection of the Pinocchio, DART and Newton adapters: those engines' step calls
have no such constraint), the engine's loop here does not do it: the ratio then
counts that physics with the adapter's overhead, and each loop's docstring says so.

:data:`NATIVE_LOOPS` maps an engine name to its loop; :data:`NOT_ISOLATED` gives the
reason for each registered engine without one.  Nothing here is used by cipval.
"""

from __future__ import annotations

import contextlib
import functools
import io
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import mujoco
import numpy as np
from mujoco import rollout

from cip.engines.drake_plant import generalized_forces
from cip.mjtimer import timers_off
from cip.model import CIPParams
from cip.runner import CIPRunner
from cipcore.params import BalanceParams


class NotIsolated(Exception):
    """An engine whose own loop is not measured here; the message says why."""


@dataclass(frozen=True)
class NativeCase:
    """What an engine's loop steps.

    Attributes
    ----------
    backend : the adapter's rollout backend (:class:`cip.runner.RolloutBackend`),
        built as the adapter builds it; it holds the engine's objects.
    state : (R, nstate) start states, MuJoCo's ``mjSTATE_FULLPHYSICS`` (time s,
        qpos, qvel).
    ctrl : (R, nu) MuJoCo controls held over every step (the motors' entries
        M beta e(0), N before the gear).
    steps : steps per realisation.
    """

    backend: Any
    state: np.ndarray
    ctrl: np.ndarray
    steps: int

    @property
    def n_realizations(self) -> int:
        return self.state.shape[0]


def make_case(
    engine: Any,
    model: str,
    params: BalanceParams,
    n_realizations: int,
    steps: int,
    amplitude: float,
) -> NativeCase:
    """The :class:`NativeCase` of ``engine`` (a registry engine object) on ``model``
    ("single" or "coupled") at ``params``, tilted to the balancing error ``amplitude``
    (m), as ``engine.simulate(model, params, ..., amplitude=amplitude)`` starts it.

    Raises :class:`NotIsolated` for an engine with no rollout backend (no engine
    loop beneath the adapter)."""
    backend = getattr(engine, "rollout", None)
    if backend is None:
        raise NotIsolated("no rollout backend: the adapter steps no engine of its own")
    physical = CIPParams.from_reduced(params)
    runner = CIPRunner(model, params, physical, n_realizations, amplitude, threads=1,
                       backend=backend())  # fmt: skip
    ctrl = np.zeros((n_realizations, runner.m.nu))
    ctrl[:, runner.i_u] = physical.cart_mass * params.beta * runner.e_hist[:, -1]
    return NativeCase(runner.backend, runner.state.copy(), ctrl, steps)


def held_forces(case: NativeCase) -> tuple[np.ndarray, np.ndarray]:
    """(cart force N, hinge torque N m), each (R, C): the held control plus the model's
    dampers at the start state (:func:`cip.engines.drake_plant.generalized_forces`),
    for a backend on :class:`cip.engines.rollout.ModelRollout`."""
    b, s = case.backend, case.state
    u = case.ctrl[:, b.motor] * b.gear
    return generalized_forces(b.geometry, s[:, b.mj_theta], s[:, b.mj_xdot], s[:, b.mj_omega], u)


def _prime(case: NativeCase) -> None:
    """One step through the adapter, which builds its lazily created per-realisation
    engine objects (clients, systems) and writes the start state into them."""
    out = np.empty((case.n_realizations, 1, case.state.shape[1]))
    case.backend(case.state, case.ctrl[:, None, :].copy(), out)


def mujoco_loop(case: NativeCase) -> float:
    """``mujoco.rollout.rollout``: one call stepping every realisation ``steps`` steps
    in C on one ``MjData``, the model copy the adapter steps (sensors and unused
    constraint stages off) with MuJoCo's timers off, as the adapter runs it
    (:mod:`cip.mjtimer`).  Returns the seconds of the call."""
    b, R, n = case.backend, case.n_realizations, case.steps
    m = b.models[0]
    ctrl = np.ascontiguousarray(np.broadcast_to(case.ctrl[:, None, :], (R, n, m.nu)))
    out = np.empty((R, n, case.state.shape[1]))
    sens = np.empty((R, n, m.nsensordata))
    datas = [mujoco.MjData(m)]
    with timers_off():
        t0 = time.perf_counter()
        rollout.rollout(b.models[:R], datas, case.state, ctrl, nstep=n, skip_checks=True,
                        state=out, sensordata=sens)  # fmt: skip
        return time.perf_counter() - t0


@functools.cache
def _mjx_scan(steps: int) -> Callable[..., Any]:
    """jit(vmap(scan of ``mujoco.mjx.step`` over ``steps`` steps)), the control held."""
    import jax

    jax.config.update("jax_enable_x64", True)
    with contextlib.redirect_stdout(io.StringIO()):  # "Failed to import warp" on stdout
        from mujoco import mjx

    def run(mx: Any, qpos: Any, qvel: Any, ctrl: Any) -> tuple[Any, Any]:
        d0 = mjx.make_data(mx).replace(ctrl=ctrl)

        def body(carry: tuple, _: None) -> tuple[tuple, None]:
            q, v, w = carry
            d = mjx.step(mx, d0.replace(qpos=q, qvel=v, qacc_warmstart=w))
            return (d.qpos, d.qvel, d.qacc_warmstart), None

        (q, v, _), _ = jax.lax.scan(body, (qpos, qvel, d0.qacc_warmstart), None, length=steps)
        return q, v

    return jax.jit(jax.vmap(run, in_axes=(None, 0, 0, 0)))


def mjx_loop(case: NativeCase) -> float:
    """``mujoco.mjx.step`` in a jitted ``jax.lax.scan`` over ``steps`` steps, vmapped over
    the realisations, float64, on the adapter's model (its declared one-iteration Newton
    solve, ``MJXRollout.model``).  The carry is qpos, qvel and the solver's warm start, as
    the adapter's (a whole ``mjx.Data`` carry fails under x64).  Compiled on the first
    call; returns the seconds of the compiled call, results ready."""
    from mujoco import mjx

    b, n = case.backend, case.steps
    nq, nv = b.model.nq, b.model.nv
    fn = _mjx_scan(n)
    mx = mjx.put_model(b.model)
    q, v = case.state[:, 1 : 1 + nq], case.state[:, 1 + nq : 1 + nq + nv]
    t0 = time.perf_counter()
    for x in fn(mx, q, v, case.ctrl):
        x.block_until_ready()
    return time.perf_counter() - t0


def drake_loop(case: NativeCase) -> float:
    """``MultibodyPlant.ExecuteForcedEvents``: one discrete SAP step of dt of one
    realisation's ``Context`` (the adapter's plant and contexts), the generalised forces
    fixed once on the applied-force input port.  Returns the seconds of the steps."""
    b, R = case.backend, case.n_realizations
    plant, c = b.plant, b.cip
    f_cart, t_hinge = held_forces(case)
    x = np.zeros((R, b.nx))
    x[:, b.drake_index] = case.state[:, b.mj_index]
    tau = np.zeros((R, plant.num_velocities()))
    tau[:, c.v_x], tau[:, c.v_theta] = f_cart, t_hinge
    contexts = b.contexts[:R]
    for r, ctx in enumerate(contexts):
        plant.SetPositionsAndVelocities(ctx, x[r])
        b.port.FixValue(ctx, tau[r])
    step = plant.ExecuteForcedEvents
    t0 = time.perf_counter()
    for _ in range(case.steps):
        for ctx in contexts:
            step(ctx)
    return time.perf_counter() - t0


def bullet_loop(case: NativeCase) -> float:
    """``pybullet.stepSimulation`` per physics client (one client per realisation, the
    adapter's), with the forces set by ``setJointMotorControlArray(TORQUE_CONTROL)``
    before every step: Bullet applies a torque for one step only, so holding a control
    takes that call each step.  Starts one step in (the adapter's first step builds the
    clients).  Returns the seconds of the steps."""
    _prime(case)
    b, pb = case.backend, case.backend.pb
    f_cart, t_hinge = held_forces(case)
    torque = pb.TORQUE_CONTROL
    elapsed = 0.0
    for r in range(case.n_realizations):
        cid, bodies = b.clients[r]
        forces = [[float(f), float(t)] for f, t in zip(f_cart[r], t_hinge[r], strict=True)]
        t0 = time.perf_counter()
        for _ in range(case.steps):
            for body, f in zip(bodies, forces, strict=True):
                pb.setJointMotorControlArray(body, [0, 1], torque, forces=f, physicsClientId=cid)
            pb.stepSimulation(physicsClientId=cid)
        elapsed += time.perf_counter() - t0
    return elapsed


def exudyn_loop(case: NativeCase) -> float:
    """``MainSolverImplicitSecondOrder.SolveSteps``: one Newmark step of dt of one
    realisation's system (the adapter's systems and solver settings), its end time
    advanced by dt before each call; the x loads on carts and bobs set once.  Returns
    the seconds of the steps."""
    _prime(case)
    b = case.backend
    elapsed = 0.0
    for r in range(case.n_realizations):
        sysr = b.systems[r]
        q, qd = b.to_exudyn(case.state[r])
        sysr.start(q, qd)
        qd4 = qd.reshape(b.nc, 4)
        f_cart = case.ctrl[r, b.motor] * b.gear - b.c_cart * qd4[:, 0]
        f_bob = -b.c_tip * qd4[:, 2]
        for i, load in enumerate(sysr.cart_load):
            sysr.mbs.SetLoadParameter(load, "load", float(f_cart[i]))
            sysr.mbs.SetLoadParameter(sysr.bob_load[i], "load", float(f_bob[i]))
        solver, mbs, ss, dt = sysr.solver, sysr.mbs, sysr.ss, sysr.dt
        t0 = time.perf_counter()
        for k in range(1, case.steps + 1):
            solver.it.endTime = k * dt
            solver.SolveSteps(mbs, ss)
        elapsed += time.perf_counter() - t0
    return elapsed


def simbody_loop(case: NativeCase) -> float:
    """``opensim.Manager.integrate``: one fixed RK-Merson step of dt per call, one manager
    per realisation on the adapter's OpenSim model, the actuators' override forces set
    once on the manager's state.  Returns the seconds of the steps."""
    b, dt = case.backend, case.backend.dt
    om, qi = b.osim_model, b.osim_model.q_index
    f_cart, t_hinge = held_forces(case)
    managers = []
    for r in range(case.n_realizations):
        q, u = np.empty(len(qi)), np.empty(len(qi))
        q[qi], u[qi] = case.state[r, b.mj_q], case.state[r, b.mj_v]
        mgr = om.manager(q, u, dt, 0.0)
        s = mgr.getState()
        for a, f in zip(om.actuators, np.r_[f_cart[r], t_hinge[r]], strict=True):
            a.setOverrideActuation(s, float(f))
        managers.append(mgr)
    t0 = time.perf_counter()
    for mgr in managers:
        for k in range(1, case.steps + 1):
            mgr.integrate(k * dt)
    return time.perf_counter() - t0


def pinocchio_loop(case: NativeCase) -> float:
    """``pinocchio.aba`` and ``pinocchio.integrate``: semi-implicit Euler,
    v+ = v + dt aba(q, v, tau), q+ = integrate(q, dt v+), as the adapter steps, on its
    model and data, tau held.  Without the rod: Pinocchio has no constraint in this
    step; the adapter's rigid-rod projection (Jacobians, ``computeMinverse``) is its
    own physics, so the ratio counts it.  Returns the seconds of the steps."""
    b, dt = case.backend, case.backend.dt
    pin, model, data, c = b.pin, b.model, b.data, b.cip
    f_cart, t_hinge = held_forces(case)
    aba, integrate = pin.aba, pin.integrate
    elapsed = 0.0
    for r in range(case.n_realizations):
        q, v, tau = np.zeros(b.nq), np.zeros(b.nv), np.zeros(b.nv)
        q[b.pin_q], v[b.pin_v] = case.state[r, b.mj_q], case.state[r, b.mj_v]
        tau[c.v_x], tau[c.v_theta] = f_cart[r], t_hinge[r]
        t0 = time.perf_counter()
        for _ in range(case.steps):
            v = v + dt * aba(model, data, q, v, tau)
            q = integrate(model, q, dt * v)
        elapsed += time.perf_counter() - t0
    return elapsed


def dart_loop(case: NativeCase) -> float:
    """``Skeleton.computeForwardDynamics``, ``integrateVelocities`` and
    ``integratePositions``: DART's semi-implicit Euler step of each of the adapter's
    skeletons (what the adapter calls; it steps no ``World``), the generalised forces
    set once.  Without the rod: the adapter's velocity projection is its own physics
    in Python, so the ratio counts it.  Returns the seconds of the steps."""
    b, dt = case.backend, case.backend.dt
    skels = b.cip.skeletons
    f_cart, t_hinge = held_forces(case)
    elapsed = 0.0
    for r in range(case.n_realizations):
        q, v = case.state[r, b.mj_qc], case.state[r, b.mj_vc]  # (C, 2)
        for i, skel in enumerate(skels):
            skel.setPositions(q[i])
            skel.setVelocities(v[i])
            skel.clearExternalForces()
            skel.setForces(np.array([f_cart[r, i], t_hinge[r, i]]))
        t0 = time.perf_counter()
        for _ in range(case.steps):
            for skel in skels:
                skel.computeForwardDynamics()
                skel.integrateVelocities(dt)
            for skel in skels:
                skel.integratePositions(dt)
        elapsed += time.perf_counter() - t0
    return elapsed


def physx_loop(case: NativeCase) -> float:
    """``sapien.physx.PhysxCpuSystem.step``: one PhysX step of dt of the adapter's scene
    (every realisation a copy of the articulations in it), the joint forces set once
    (``set_qf``: PhysX keeps them).  Returns the seconds of the steps."""
    b, R = case.backend, case.n_realizations
    f_cart, t_hinge = held_forces(case)
    for r in range(R):
        for i, art in enumerate(b.cip.articulations[r]):
            art.set_qpos(case.state[r, [b.mj_x[i], b.mj_theta[i]]].astype(np.float32))
            art.set_qvel(case.state[r, [b.mj_xdot[i], b.mj_omega[i]]].astype(np.float32))
            art.set_qf(np.array([f_cart[r, i], t_hinge[r, i]], np.float32))
    step = b.cip.system.step
    t0 = time.perf_counter()
    for _ in range(case.steps):
        step()
    return time.perf_counter() - t0


def newton_loop(case: NativeCase) -> float:
    """``SolverFeatherstone.step``: one step of dt of every world of the adapter's batch
    (warp's CPU device), the two states swapped after each, ``Control.joint_f`` set
    once.  Without the rod: Featherstone has no loop closure, the adapter's velocity
    projection is its own physics in Python, so the ratio counts it.  Returns the
    seconds of the steps."""
    b, R = case.backend, case.n_realizations
    shape = (R, b.nc, 2)
    s0, s1 = b.states
    f_cart, t_hinge = held_forces(case)
    s0.joint_q.numpy().reshape(shape)[:] = case.state[:, b.mj_qc]
    s0.joint_qd.numpy().reshape(shape)[:] = case.state[:, b.mj_vc]
    joint_f = b.control.joint_f.numpy().reshape(shape)
    joint_f[..., 0], joint_f[..., 1] = f_cart, t_hinge
    step, control, dt = b.solver.step, b.control, b.dt
    t0 = time.perf_counter()
    for _ in range(case.steps):
        step(s0, s1, control, None, dt)
        s0, s1 = s1, s0
    return time.perf_counter() - t0


#: engine name -> its own loop: (case) -> seconds of the timed steps
NATIVE_LOOPS: dict[str, Callable[[NativeCase], float]] = {
    "mujoco": mujoco_loop,
    "mjx": mjx_loop,
    "drake": drake_loop,
    "bullet": bullet_loop,
    "exudyn": exudyn_loop,
    "simbody": simbody_loop,
    "pinocchio": pinocchio_loop,
    "dart": dart_loop,
    "physx": physx_loop,
    "newton": newton_loop,
}

#: registered engines without a loop here, and why
NOT_ISOLATED: dict[str, str] = {
    "reduced": "cipval's own reference model: the adapter is the engine",
    "reduced-gpu": "cipval's own reference model in warp kernels: the adapter is the engine",
    "mujoco-warp": "not written: MuJoCo Warp needs a CUDA device, none here to check a loop on",
    "genesis": "not written: genesis is not installed here, so no loop could be checked",
}


def native_loop(name: str) -> Callable[[NativeCase], float]:
    """Engine ``name``'s own loop (:data:`NATIVE_LOOPS`); raises :class:`NotIsolated`
    with the reason where there is none."""
    loop = NATIVE_LOOPS.get(name)
    if loop is None:
        raise NotIsolated(NOT_ISOLATED.get(name, "no loop in benchmarks/native_loops.py"))
    return loop
