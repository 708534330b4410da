"""Genesis as a registered engine: the CIP in Genesis's rigid solver, on its CPU backend.

Genesis (``genesis-world``) builds articulated bodies only from description files
(MJCF, URDF, USD: it has no API that adds a joint or a body), and it parses an MJCF by
compiling it with MuJoCo and reading the compiled model.  The shipped model files are
not handed to it as they are: the backend is given a compiled ``mujoco.MjModel`` (the
file as a user, a fault or the refinement check edited it), Genesis's MJCF loader
refuses the coupled file's rod (a tendon equality: "Unsupported MJCF equality object
type") and leaves the single file's actuators unparsed (two actuators on the cart's
slide).  Every physical number is instead read from the compiled MuJoCo model
(:func:`cip.engines.drake_plant.geometry_from_mujoco`) and written into a minimal MJCF
document (:func:`mjcf_document`: the kinematic tree and its inertias, nothing else),
which Genesis loads through ``gs.morphs.MJCF``; per controller i:

* cart: a body ``cart_<i>`` at the cart's reference position (x = -+l/2 in the coupled
  model) on a slide joint ``x_M<i>`` along world +x (so that the coordinate is the MJCF
  ``qpos`` of the slide, m), carrying the cart's mass M (kg) at its origin (its
  rotational inertia, M on each axis, is never excited: the cart only translates);
* pendulum: a body ``pendulum_<i>`` at the cart's origin on a hinge ``theta_<i>`` about
  +y (theta > 0 tilts the tip to +x, as in MuJoCo), carrying the massless pole's bob:
  mass m at (0, 0, L) with the MJCF's central inertia;
* no geometry (nothing collides or is drawn), no actuator, limit, spring, damper or
  equality; gravity and the time step are the scene's (``SimOptions``), from the model.

Genesis's own additions are switched off and checked: its default rotor armature (0.1
on every hinge and slide, ``default_armature=None``), collisions, joint limits and
its constraint solver (``RigidOptions``).  After the build, :func:`verify_scene` reads
back what Genesis took and compares it with the geometry: the link masses, centres of
mass and inertias, zero damping, armature, stiffness and friction loss, unbounded
force ranges and limits, the gravity of every environment, the time step and one
substep; and, as one check of the whole tree (axes, lengths, masses, gravity, the
Coriolis terms), Genesis's unconstrained acceleration at a tilted, moving probe state
against MuJoCo's M^-1 (-qfrc_bias) of the given model at the same state (relative
:data:`PROBE_TOLERANCE`).  A mismatch raises :class:`GenesisModelError`.

The step (one ``scene.step()`` per dt, all realisations at once: one Genesis
environment each, ``scene.build(n_envs=R)``): the control and the MJCF's damping are
generalised forces evaluated at the state at the start of the step, explicit as in
MuJoCo's ``Euler`` (:func:`cip.engines.drake_plant.generalized_forces`: the motor
gear u and the cart damping -c_cart v_M on the cart, the tip damping
F_t = -c_tip v_tip,x through the tip's x Jacobian, v_tip,x = v_M + L cos(theta)
theta'), handed to Genesis as ``control_dofs_force``.  Genesis's rigid solver with
``integrator=gs.integrator.Euler`` then computes the unconstrained acceleration
a = M(q)^-1 (tau - c(q, v)) (its composite-rigid-body mass matrix and recursive
Newton-Euler bias force) and integrates semi-implicitly, v+ = v + dt a,
q+ = q + dt v+ (``func_integrate`` of ``genesis/engine/solvers/rigid/abd/
forward_dynamics.py``, Genesis 1.4.5; its implicit damping pass does nothing when no
dof has damping, and its midpoint rule applies to free bodies only, under the other
integrators): MuJoCo's ``Euler`` scheme, order 1.  The single model's step is
therefore MuJoCo's ``Euler`` step up to rounding (measured in the module's tests).

The rod (coupled model) is a **rigid** distance constraint between the tips,
g(q) = |p_tip,1 - p_tip,2| - l.  Genesis 1.4 has no distance constraint (its
equalities are connect, weld, joint and screw: a rod body pinned by two connect
equalities would add the rod's mass and go through Genesis's soft constraint solver),
so the rod is cipval's velocity projection on Genesis's state, as in the DART engine:
after Genesis's unconstrained step, v+ = v_free + M^-1 J^T lambda with
J v+ = -g(q) / dt, J = dg/dq (1 x nv) at the step's start q (the tips'
kinematics, p_tip = (x0 + x + L sin(theta), 0, L cos(theta)), written from the
geometry), M the joint-space inertia Genesis computed for that step
(``get_mass_mat``: M(q) at the start of the step), lambda = -(J v_free + g / dt) /
(J M^-1 J^T), and q+ = q + dt v+ (Moreau's time stepping of a bilateral constraint,
full position correction), written back into Genesis (``set_qpos``,
``set_dofs_velocity``) before the next step.

Validation: no exact twin of cipval's (``capabilities.twin`` None) is claimed, so
cipval judges the engine by time-step refinement (:mod:`validation.checks.refinement`):
the open-loop trajectories at dt = h .. h/8 converge, order 1, to the exact
zero-order-hold solution of the linearised rigid body (the rod rigid).  Measured
(genesis-world 1.4.5, torch 2.13.0+cpu, ``refinement_check``, seed 1): E0 9.6e-9
(interval up to 8.8e-8) and observed order 1.002 on the single model, E0 1.5e-8 (up to
1.4e-7) and order 1.002 on the coupled one (floor 1e-6, least order 0.7), the
Pinocchio and DART engines' numbers; a 1e-3 error of the tip mass
(``make_fault("mass_ratio", 1e-3)``) moves E0 to 1.5e-4 / 1.0e-4 and fails.  Against
``mujoco.rollout`` on the single model (2 band-limited open-loop forces, 0.5 s, tilted
0.01 rad, seed 3) the relative L2 distance of (qpos, qvel) is 5.6e-17, round-off; on
the coupled model 1.9e-7 (MuJoCo's soft rod against this rigid one, as DART's 1.8e-7).
The probe of :func:`verify_scene` agrees with MuJoCo to 1.6e-14.  The rod's stretch
stays below 2.1e-12 m over 2 s of band-limited forcing (3 realisations, up to 0.024
rad); in the contract's rod check, 3.7e-12 m.

Precision and runtime: ``gs.init(backend=gs.cpu, precision="64")`` (float64 state and
kernels; Genesis compiles its kernels with fast-math, so rounding may differ from
MuJoCo's in the last bits), once per process; a process in which Genesis was already
initialised otherwise (another backend or float32) is refused.  Genesis runs its CPU
kernels on one thread (its default without ``QD_NUM_THREADS``), so the engine runs one
realisation block (``max_threads`` 1) and batches the realisations as environments.
Genesis compiles its kernels on the first build of a process: measured (2-core machine,
load 4-5) 22 s for the first scene and its first chunk on a cold kernel cache
(``$XDG_CACHE_HOME/quadrants``, by default ``~/.cache/quadrants``), 10 s from a warm
one, a later scene in the same process 0.3 s; importing Genesis (torch) and
``gs.init`` take another 15-20 s at that load.  Speed (one process, 2 s of forcing,
best of 3, load 1.3-1.8): the step costs about 260 us for the batch on the single model
and 610 us on the coupled one (the rod's state written back each step), whatever the
batch up to 16 realisations: 3.8e3 realisation-steps/s for one realisation, 5.7e4 for 16,
2.0e5 for 64 on the single model; 1.6e3, 2.3e4 and 7.8e4 on the coupled one.

The state passed in at each chunk is read afresh (positions and velocities from the
``mjSTATE_FULLPHYSICS`` vector): nothing is carried between calls;
each environment is stepped on its own, so the numbers of a realisation do not depend
on its batch (measured bit-identical alone, in a batch of 3 and in blocks of 2).
A state or force beyond :data:`MAXVAL` stops the realisation (NaN from that step) and
resets its environment, before Genesis sees an overflow (a NaN halts Genesis's whole
scene).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import mujoco
import numpy as np

from cip.engines.drake_plant import CIPGeometry, generalized_forces
from cip.engines.rigid_body import RigidBodyEngine, semi_implicit_rigid
from cip.engines.rollout import ModelRollout
from cip.names import cart_body, cart_joint, hinge_joint, pendulum_body

#: Relative L2 distance of the balancing error to the reduced model allowed at 1e-6 m:
#: the value of the other semi-implicit Euler engines with a rigid rod (Bullet,
#: Pinocchio, DART): the floor is the rigid body's cart reaction m/M (at most 3.5e-3
#: over 10 s), every control one step late gives at least 6.2e-3.
TRAJECTORY_TOLERANCE = 5e-3

#: The largest magnitude of a state coordinate or force that the step accepts:
#: MuJoCo's ``mjMAXVAL``.  A NaN in one Genesis environment halts the whole scene
#: (``INVALID_ACC_NAN``), so a realisation is stopped at the first state or force beyond
#: this bound (NaN from that step, as the other engines' overflow).
MAXVAL = 1e10

#: Largest relative distance between Genesis's unconstrained acceleration at the probe
#: state and MuJoCo's (:func:`verify_scene`): float64 rounding with margin.
PROBE_TOLERANCE = 1e-10

#: The probe state of :func:`verify_scene`: per controller (x, theta, x', theta').
PROBE_STATE = (0.02, 0.3, -0.4, 1.5)


class GenesisModelError(RuntimeError):
    """Genesis took a parameter other than the one the MuJoCo model states."""


def _genesis():
    """Genesis, initialised on its CPU backend in float64 (once per process)."""
    import genesis as gs

    if not getattr(gs, "_initialized", False):
        gs.init(backend=gs.cpu, precision="64", logging_level="warning")
    if gs.backend != gs.cpu or np.dtype(gs.np_float) != np.float64:
        raise GenesisModelError(
            f"Genesis was initialised in this process on {gs.backend} with {gs.np_float}: the "
            "genesis engine needs gs.init(backend=gs.cpu, precision='64')"
        )
    return gs


def mjcf_document(g: CIPGeometry) -> str:
    """The MJCF that Genesis loads for the CIP described by ``g`` (module docstring).

    Numbers are written with ``repr`` (the shortest text that reads back as the same
    float64), so MuJoCo's compile of the document reproduces them exactly.
    """
    bodies = []
    for i in range(g.n_controllers):
        M, m, L = g.cart_mass[i], g.bob_mass[i], g.pendulum_length[i]
        inertia = " ".join(repr(v) for v in g.bob_inertia[i])
        bodies.append(
            f'<body name="{cart_body(i + 1)}" pos="{g.cart_x0[i]!r} 0 0">'
            f'<joint name="{cart_joint(i + 1)}" type="slide" axis="1 0 0"/>'
            f'<inertial pos="0 0 0" mass="{M!r}" diaginertia="{M!r} {M!r} {M!r}"/>'
            f'<body name="{pendulum_body(i + 1)}" pos="0 0 0">'
            f'<joint name="{hinge_joint(i + 1)}" type="hinge" axis="0 1 0"/>'
            f'<inertial pos="0 0 {L!r}" mass="{m!r}" diaginertia="{inertia}"/>'
            "</body></body>"
        )
    return (
        '<mujoco model="cip_genesis"><compiler angle="radian"/>'
        f"<worldbody>{''.join(bodies)}</worldbody></mujoco>"
    )


@dataclass
class GenesisCIP:
    """A built Genesis scene of the CIP and where its coordinates live.

    ``q_x``, ``q_theta`` index the entity's qpos, ``v_x``, ``v_theta`` its dofs (one
    entry per controller); ``n_envs`` environments (realisations) step at once.
    """

    scene: Any
    entity: Any
    geometry: CIPGeometry
    n_envs: int
    q_x: np.ndarray
    q_theta: np.ndarray
    v_x: np.ndarray
    v_theta: np.ndarray


def build_scene(g: CIPGeometry, n_envs: int) -> GenesisCIP:
    """The built Genesis scene of the CIP described by ``g``, ``n_envs`` environments."""
    gs = _genesis()
    scene = gs.Scene(
        sim_options=gs.options.SimOptions(dt=g.timestep, substeps=1, gravity=g.gravity),
        rigid_options=gs.options.RigidOptions(
            integrator=gs.integrator.Euler,
            enable_collision=False,
            enable_joint_limit=False,
            disable_constraint=True,
        ),
        show_viewer=False,
    )
    entity = scene.add_entity(gs.morphs.MJCF(file=mjcf_document(g), default_armature=None))
    scene.build(n_envs=n_envs)

    def qs(name: str) -> int:
        return int(entity.get_joint(name).qs_idx_local[0])

    def dofs(name: str) -> int:
        return int(entity.get_joint(name).dofs_idx_local[0])

    nc = range(1, g.n_controllers + 1)
    return GenesisCIP(
        scene=scene,
        entity=entity,
        geometry=g,
        n_envs=n_envs,
        q_x=np.array([qs(cart_joint(i)) for i in nc]),
        q_theta=np.array([qs(hinge_joint(i)) for i in nc]),
        v_x=np.array([dofs(cart_joint(i)) for i in nc]),
        v_theta=np.array([dofs(hinge_joint(i)) for i in nc]),
    )


def _expect(what: str, took: Any, expected: Any, rtol: float = 0.0) -> None:
    took, expected = np.asarray(took, dtype=float), np.asarray(expected, dtype=float)
    if took.shape != expected.shape or not np.allclose(took, expected, rtol=rtol, atol=0.0):
        raise GenesisModelError(f"Genesis took {what} {took.tolist()}, the model states {expected}")


def _numpy(t: Any) -> np.ndarray:
    """A C-ordered float64 copy of a Genesis (torch) tensor.

    C order whatever the tensor's layout (Genesis returns batched quantities as
    transposed views for some batch sizes and not others): NumPy's reductions follow the
    memory layout, so a realisation's numbers would otherwise depend on its batch."""
    return np.array(t.cpu().numpy(), dtype=float, order="C")


def verify_scene(c: GenesisCIP, m: mujoco.MjModel) -> float:
    """Compare what Genesis took with the geometry and the MuJoCo model ``m``.

    Raises :class:`GenesisModelError` on the first mismatch (module docstring); returns
    the relative distance of Genesis's unconstrained acceleration at the probe state to
    MuJoCo's.  Leaves the scene's state at the end of the probe step (each rollout call
    sets its own).
    """
    g, ent, solver = c.geometry, c.entity, c.scene.sim.rigid_solver
    links = [
        ent.get_link(n)
        for i in range(1, g.n_controllers + 1)
        for n in (cart_body(i), pendulum_body(i))
    ]
    idx = [link.idx_local for link in links]
    mass, com = _numpy(ent.get_links_mass(idx)), _numpy(ent.get_links_COM(idx))
    inertia = _numpy(ent.get_links_inertia(idx))
    if mass.ndim == 2:  # per environment (batched link information)
        mass, com, inertia = mass[0], com[0], inertia[0]
    for i in range(g.n_controllers):
        M, m_bob, L = g.cart_mass[i], g.bob_mass[i], g.pendulum_length[i]
        _expect(
            f"the masses of {cart_body(i + 1)}, {pendulum_body(i + 1)}",
            mass[2 * i : 2 * i + 2],
            (M, m_bob),
        )
        _expect(f"the centre of mass of {pendulum_body(i + 1)}", com[2 * i + 1], (0.0, 0.0, L))
        _expect(f"the centre of mass of {cart_body(i + 1)}", com[2 * i], (0.0, 0.0, 0.0))
        _expect(
            f"the inertia of {pendulum_body(i + 1)}", inertia[2 * i + 1], np.diag(g.bob_inertia[i])
        )
        _expect(f"the inertia of {cart_body(i + 1)}", inertia[2 * i], M * np.eye(3))
    nv = ent.n_dofs
    for name in ("damping", "armature", "stiffness", "frictionloss"):
        _expect(
            f"the dofs' {name}",
            _numpy(getattr(ent, f"get_dofs_{name}")()).reshape(-1, nv)[0],
            np.zeros(nv),
        )
    unbounded = np.r_[np.full(nv, -np.inf), np.full(nv, np.inf)]
    for name in ("force_range", "limit"):
        lo, hi = (_numpy(t).reshape(-1, nv)[0] for t in getattr(ent, f"get_dofs_{name}")())
        _expect(f"the dofs' {name}", np.r_[lo, hi], unbounded)
    _expect(
        "the gravity",
        _numpy(solver.get_gravity()).reshape(-1, 3),
        np.tile(g.gravity, (c.n_envs, 1)),
    )
    _expect("the time step and substeps", (solver.substep_dt, solver.substeps), (g.timestep, 1))
    return _probe(c, m)


def _probe(c: GenesisCIP, m: mujoco.MjModel) -> float:
    """Relative distance of Genesis's unconstrained acceleration at :data:`PROBE_STATE`
    (no force: one step, (v+ - v) / dt) to MuJoCo's M^-1 (-qfrc_bias) of ``m``."""
    g, ent = c.geometry, c.entity
    x, theta, xd, thd = PROBE_STATE
    sign = np.array([(-1.0) ** i for i in range(g.n_controllers)])  # mirror the second balancer
    q_gs, v_gs = np.zeros((c.n_envs, ent.n_qs)), np.zeros((c.n_envs, ent.n_dofs))
    q_gs[:, c.q_x], q_gs[:, c.q_theta] = x * sign, theta * sign
    v_gs[:, c.v_x], v_gs[:, c.v_theta] = xd * sign, thd * sign
    ent.set_qpos(q_gs, zero_velocity=False)
    ent.set_dofs_velocity(v_gs)
    ent.control_dofs_force(np.zeros((c.n_envs, ent.n_dofs)))
    c.scene.step()
    a_gs = (_numpy(ent.get_dofs_velocity()) - v_gs) / g.timestep
    d = mujoco.MjData(m)
    d.qpos[list(g.qpos_x)], d.qpos[list(g.qpos_theta)] = x * sign, theta * sign
    d.qvel[list(g.dof_x)], d.qvel[list(g.dof_theta)] = xd * sign, thd * sign
    mujoco.mj_forward(m, d)
    a_mj = np.zeros(m.nv)
    mujoco.mj_solveM(m, d, a_mj[None], -d.qfrc_bias[None])
    want = np.empty(ent.n_dofs)
    want[c.v_x], want[c.v_theta] = a_mj[list(g.dof_x)], a_mj[list(g.dof_theta)]
    dist = float(np.abs(a_gs - want).max() / np.abs(want).max())
    if not dist <= PROBE_TOLERANCE:
        raise GenesisModelError(
            f"Genesis's acceleration at the probe state {a_gs[0].tolist()} differs from "
            f"MuJoCo's {want.tolist()} by {dist:.2g} (relative; at most {PROBE_TOLERANCE:g})"
        )
    return dist


class GenesisRollout(ModelRollout):
    """:class:`cip.runner.RolloutBackend` stepping the CIP with Genesis (module docstring).

    Parameters
    ----------
    model : the compiled MuJoCo CIP (:func:`cip.model.build`): the source of every
        physical parameter, the time step (``model.opt.timestep``) and the state layout.
    n_realizations : number of realisations: one Genesis environment each, stepped
        together (a call with more realisations steps them in blocks of this size).
    threads : ignored (Genesis's CPU kernels run on one thread; the engine's
        ``max_threads`` is 1).
    """

    @staticmethod
    def preload() -> None:
        """Import and initialise Genesis (seconds: torch)."""
        _genesis()

    def __init__(self, model: mujoco.MjModel, n_realizations: int, threads: int) -> None:
        super().__init__(model)
        g = self.geometry
        c = self.cip = build_scene(g, max(1, int(n_realizations)))
        self.probe_distance = verify_scene(c, model)
        self.nc = g.n_controllers
        self.gs_q = np.r_[c.q_x, c.q_theta]
        self.gs_v = np.r_[c.v_x, c.v_theta]
        self.x0 = np.array(g.cart_x0)
        self.length = np.array(g.pendulum_length)
        self.rod = g.rod_length

    def close(self) -> None:
        """Release the Genesis scene (the refinement check builds one per time step)."""
        scene = getattr(self, "cip", None)
        if scene is not None:
            scene.scene.destroy()
            self.cip = None

    def _forces(self, q: np.ndarray, v: np.ndarray, u: np.ndarray) -> np.ndarray:
        """Generalised forces (B, nv) in Genesis's dof order at the state (q, v), motor
        forces ``u`` (B, C) (N): the control and the MJCF's dampers, explicit."""
        c = self.cip
        f_cart, tau = generalized_forces(
            self.geometry, q[:, c.q_theta], v[:, c.v_x], v[:, c.v_theta], u
        )
        out = np.zeros_like(v)
        out[:, c.v_x], out[:, c.v_theta] = f_cart, tau
        return out

    def _project(self, q: np.ndarray, q1: np.ndarray, v1: np.ndarray) -> None:
        """Project Genesis's free end velocities ``v1`` onto J v+ = -g(q) / dt and set
        q1 = q + dt v+, in place (module docstring); q the start-of-step positions."""
        c, L = self.cip, self.length
        th = q[:, c.q_theta]
        tip_x = self.x0 + q[:, c.q_x] + L * np.sin(th)  # (B, 2)
        tip_z = L * np.cos(th)
        dx, dz = tip_x[:, 0] - tip_x[:, 1], tip_z[:, 0] - tip_z[:, 1]
        dist = np.hypot(dx, dz)
        nx, nz = dx / dist, dz / dist
        arm = L * (nx[:, None] * np.cos(th) - nz[:, None] * np.sin(th))  # n . dp_tip/dtheta
        jac = np.zeros_like(v1)
        jac[:, c.v_x] = nx[:, None] * [1.0, -1.0]
        jac[:, c.v_theta] = arm * [1.0, -1.0]
        w = np.linalg.solve(_numpy(c.entity.get_mass_mat()), jac[..., None])[..., 0]  # M^-1 J^T
        lam = -((jac * v1).sum(axis=1) + (dist - self.rod) / self.dt) / (jac * w).sum(axis=1)
        v1 += lam[:, None] * w
        q1[:] = q + self.dt * v1

    def _block(self, q: np.ndarray, v: np.ndarray, u: np.ndarray) -> tuple:
        """Step one block of B <= n_envs realisations from (q, v) (B, nq), (B, nv) in
        Genesis's order under motor forces ``u`` (B, n, C): the positions and velocities
        after each step, (B, n, nq) and (B, n, nv), and the first bad step of each
        realisation (n where none)."""
        c = self.cip
        ent, scene, n_envs = c.entity, c.scene, c.n_envs
        B, n = u.shape[:2]
        pad = np.zeros((n_envs, ent.n_qs)), np.zeros((n_envs, ent.n_dofs))
        pad[0][:B], pad[1][:B] = q, v
        q, v = pad
        bad = np.full(n_envs, n)
        bad[B:] = n + 1  # padding: never recorded
        live = np.ones(n_envs, dtype=bool)
        u_all = np.zeros((n_envs, n, u.shape[2]))
        u_all[:B] = u
        qs, vs = np.empty((n_envs, n, ent.n_qs)), np.empty((n_envs, n, ent.n_dofs))
        ent.set_qpos(q, zero_velocity=False, skip_forward=True)
        ent.set_dofs_velocity(v, skip_forward=True)
        for k in range(n):
            tau = self._forces(q, v, u_all[:, k])
            tau[~live] = 0.0  # a stopped realisation's environment stays at rest
            stop = live & ~(np.abs(tau) < MAXVAL).all(axis=1)  # (NaN compares False)
            if stop.any():
                q, v, tau = self._stop(stop, k, bad, live, q, v, tau)
            ent.control_dofs_force(tau)
            scene.step()
            q1, v1 = _numpy(ent.get_qpos()), _numpy(ent.get_dofs_velocity())
            if self.rod is not None:
                self._project(q, q1, v1)
            qs[:, k], vs[:, k] = q1, v1
            stop = live & ~((np.abs(q1) < MAXVAL).all(axis=1) & (np.abs(v1) < MAXVAL).all(axis=1))
            if stop.any():
                q1, v1, _ = self._stop(stop, k, bad, live, q1, v1, tau)
            if self.rod is not None:  # the projected state, for Genesis's next step
                ent.set_qpos(q1, zero_velocity=False, skip_forward=True)
                ent.set_dofs_velocity(v1, skip_forward=True)
            q, v = q1, v1
        return qs[:B], vs[:B], bad[:B]

    def _stop(self, stop, k, bad, live, q, v, tau) -> tuple:
        """Stop the realisations ``stop`` (B,) at step k (``bad``, ``live`` updated in
        place): their environments reset to rest (zero state and force), so that no
        overflow reaches Genesis.  Returns (q, v, tau) with those rows zeroed."""
        bad[stop] = k
        live &= ~stop
        q, v, tau = q.copy(), v.copy(), tau.copy()
        q[stop], v[stop], tau[stop] = 0.0, 0.0, 0.0
        envs = np.nonzero(stop)[0]
        self.cip.entity.set_qpos(q[envs], envs_idx=envs, zero_velocity=True, skip_forward=True)
        return q, v, tau

    def __call__(self, state: np.ndarray, ctrl: np.ndarray, out: np.ndarray) -> None:
        R, n = ctrl.shape[:2]
        u = self.begin(state, ctrl, out)  # (R, n, C) cart forces, N
        c = self.cip
        q = np.zeros((R, c.entity.n_qs))
        v = np.zeros((R, c.entity.n_dofs))
        q[:, self.gs_q] = state[:, self.mj_q]
        v[:, self.gs_v] = state[:, self.mj_v]
        ok = np.isfinite(q).all(axis=1) & np.isfinite(v).all(axis=1)
        q[~ok], v[~ok] = 0.0, 0.0
        for r0 in range(0, R, c.n_envs):
            r1 = min(R, r0 + c.n_envs)
            qs, vs, bad = self._block(q[r0:r1], v[r0:r1], u[r0:r1])
            block = out[r0:r1]
            block[:, :, self.mj_q] = qs[:, :, self.gs_q]
            block[:, :, self.mj_v] = vs[:, :, self.gs_v]
            for j in np.nonzero(bad < n)[0]:  # beyond MAXVAL: NaN from there
                self.diverged(out, r0 + j, bad[j])
        out[~ok, :, 1:] = np.nan


ENGINE = RigidBodyEngine(
    name="genesis",
    capabilities=semi_implicit_rigid("Genesis", "Genesis", TRAJECTORY_TOLERANCE),
    backend=lambda: GenesisRollout,
    requires=("genesis",),
    max_threads=1,
    integrators=(),
    notes="Genesis rigid solver on its CPU backend (float64, gs.integrator.Euler), the "
    "realisations as batched environments, explicit dampers; rod as a rigid distance "
    "constraint (cipval's velocity projection on Genesis's state)",
)
