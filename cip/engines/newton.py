"""Newton as a registered engine: the CIP as a Newton articulation, on warp's CPU device.

Newton (PyPI ``newton`` 1.8, NVIDIA's physics engine on ``warp-lang``) steps the CIP
with its ``SolverFeatherstone``: a batch of float32 worlds, one per realisation, all
stepped by the same kernel launches.  Every physical number is read from the compiled
MuJoCo model (:func:`cip.engines.drake_plant.geometry_from_mujoco`), and the model is
built with Newton's ``ModelBuilder`` API (no URDF, USD or MJCF importer); per
controller i an articulation of two links:

* cart: a link of the cart's mass M (kg) on a prismatic joint ``x_M<i>`` along world
  +x from the world, the joint coordinate the MJCF ``qpos`` of the slide (m); its
  rotational inertia M I is never excited (the cart only translates).  Every rail
  runs through the world origin, not through the cart's reference position (x = +-l/2
  in the coupled model): nothing in an articulation's dynamics depends on where it
  sits along x (gravity is along z, nothing collides), but Newton's Featherstone
  computes in world-frame spatial coordinates in float32, where a rail at x = 0.5 m
  rounds the gravity torque's moment arm to 3e-8 m (the single model's refinement
  limit, seed 1, moved from 8.0e-6 to 8.9e-5 with its rail there).  Only the rod,
  cipval's projection below, uses the tips' true positions;
* pendulum: a link on a revolute joint ``theta_<i>`` about +y (theta > 0 tilts the tip
  to +x, as in MuJoCo) at the cart's origin, carrying the massless pole's bob: mass m
  at the centre of mass (0, 0, L) with the MJCF's central inertia; the tip (the MJCF's
  tip site) is that centre of mass;
* gravity: the MJCF's gravity vector (m/s^2), the ``ModelBuilder``'s.

No armature, joint damping, stiffness, drive, limit, shape or contact of Newton's own;
``finalize(skip_validation_inertia=True)`` keeps the MJCF's inertias as they are
(Newton's inertia validation would otherwise correct the point bob's 1e-12 kg m^2).

The step (one ``SolverFeatherstone.step`` of dt per step, ``angular_damping`` 0): the
control and the MJCF's damping are generalised forces evaluated at the state at the
start of the step, explicit as in MuJoCo's ``Euler``, written to ``Control.joint_f``
(:func:`cip.engines.drake_plant.generalized_forces`: on the cart u - c_cart v_M + F_t,
on the hinge F_t L cos(theta), with F_t = -c_tip v_tip,x the tip damper's force along
world x at the tip).  Newton's Featherstone then computes the joint-space inertia
H(q) (composite rigid bodies), the bias forces (recursive Newton-Euler, gravity
included), solves H a = tau - C by Cholesky and integrates semi-implicit Euler:
v+ = v + dt a, q+ = q + dt v+ (``jcalc_integrate`` of a prismatic or revolute joint).
The single model's step is therefore MuJoCo's ``Euler`` step in float32: against
``mujoco.rollout`` on the single model (4 band-limited open-loop forces of seed 3,
0.5 s, tilted 0.01 rad, |e| up to 1.2e-2 m) the relative L2 distance of (qpos, qvel)
is 5.2e-7, float32 rounding (to the Pinocchio engine, the same scheme in float64, the
same 5.2e-7).

The rod (coupled model): Newton's Featherstone solver has no loop closure (no
equality constraints; a DISTANCE joint is simulated as a FREE one, and Newton's
distance joint is supported by its XPBD solver only), so the rod is cipval's
**rigid** distance constraint between the tips, g(q) = |p_tip,1 - p_tip,2| - l,
imposed at the velocity level on Newton's step-end velocities, as the Pinocchio and
DART engines do: v+ = v_free + H^-1 J^T lambda with J v+ = -g(q) / dt (full position
correction), lambda = -(J v_free + g / dt) / (J H^-1 J^T), and q+ = q + dt v+
overwrites Newton's positions.  H is the joint-space inertia that Featherstone
assembled and factorised in this very step (``SolverFeatherstone.H``, float32, at the
step's start state); g and J = dg/dq are evaluated in float64 from the joint
coordinates (p_tip,i = (x0_i + x_i + L sin(theta_i), 0, L cos(theta_i))), not from
Newton's float32 world poses, which at x = +-0.5 m resolve the rod's length to 3e-8 m
(g / dt would turn that into velocity noise as large as the refinement's whole
response: the float32 floor of the MuJoCo Warp engine's rod).  The stretch left after
a step is the float32 rounding of the stored coordinates, corrected on the next step:
at most 4.4e-10 m over 0.5 s of forcing up to 0.01 rad.  Against the Pinocchio engine
(the same projection in float64) on the same forces the coupled model's positions are
at 2.0e-7 (relative L2) and (qpos, qvel) at 1.6e-5: the angular velocities carry the
correction of that rounding (g / dt), 4e-5 of them.

Precision: float32.  Newton 1.8 has no float64 mode (its states, model arrays and
solver buffers are ``wp.float32``), so the state handed back holds float32 values.
Validation: no exact twin of cipval's (``capabilities.twin`` None), so cipval judges
the engine by time-step refinement (:mod:`validation.checks.refinement`).  Measured
(``refine``, 4 force sequences per seed, seeds 1-10): observed order 1.000-1.002 on
both models; E0 2.9e-6 to 8.0e-6 on the single model (the interval's upper end at most
2.8e-5), 3.7e-6 to 6.0e-6 on the coupled one (at most 1.9e-5): the float32 rounding of
8000 steps of a 1e-5 m response, above the shared floor (1e-6, set for float64
engines); ``refinement_check`` therefore judges a float32 engine at its float32
setting (:data:`validation.checks.refinement.FLOAT32_SETTINGS`: |e| 1e-3 / 3e-3 m over
4 s, floors 1.2e-4 / 1.6e-4), where Newton passes at seeds 1-5 (upper end at most
6.2e-5 single, 6.4e-5 coupled, order 0.995-1.003).  At the float64 setting a 1e-3
error of the tip mass (``make_fault("mass_ratio", 1e-3)``, seeds 1-3) moves E0 to
6.8e-5 to 1.5e-4 (single, upper ends 1.2e-4 to 2.0e-4) and 9.4e-5 to 1.2e-4
(coupled, 2.0e-4 to 2.2e-4), beyond the correct engine's largest upper end (2.8e-5).

Solvers: only Featherstone can represent this model.  Newton's
``SolverSemiImplicit`` holds its joints with penalty springs of one stiffness and
damping for every joint (``joint_attach_ke``, ``joint_attach_kd``): on the 1 g bob
(central inertia 1e-12 kg m^2) the angular spring's explicit step is unstable at any
stiffness that still holds the hinge (NaN within the first 0.5 s at dt = 1 ms, with
the defaults 1e4 / 1e2 and with 1e3 / 0.5).  ``SolverXPBD`` (maximal coordinates,
Newton's own distance joint for the rod) closes the hinge by rotating the point bob
about its centre of mass (inverse inertia 1e12): its trajectories do not converge
under refinement (relative distance to the exact solution 5.9e4 at every level,
single model, seed 1, its 2 default iterations; with 8 iterations and relaxation 1
the angles of a 0.5 s open-loop run leave the Pinocchio engine's by 1e9, relative).  Its MuJoCo
solver declares ``mujoco ~= 3.17`` (cipval runs MuJoCo 4.0); ``SolverSteel``
(experimental) and ``SolverKamino`` (beta) were not tried.

Batching: the R realisations are R Newton worlds (``ModelBuilder.replicate``), so one
step is one set of kernel launches for all of them (15 ``wp.launch`` a step, whose
Python argument packing is most of a step's time).  Measured (``NewtonRollout``, best of
3 x 200 steps, idle 2-core machine, load 0.9): 0.39, 0.40 and 0.50 ms per step for 1, 8
and 64 single-model worlds, 0.44, 0.47 and 0.68 ms for the coupled model (1.3e5 and
9.4e4 realisation-steps per second at 64 worlds; the Pinocchio engine, one realisation
at a time in float64, 1.2e5 and 4.4e4 with 8).  The worlds
share no kernel reduction and the host's per-step arithmetic is element-wise per
realisation, so a realisation's numbers do not depend on its batch (bit-identical for
batches of 1, 3 and 4 and a NaN neighbour, and on a rerun: :data:`ENGINE` declares
``deterministic``).  Warp compiles Newton's kernels for the CPU on first use: 24 s of
CPU once per machine (an empty kernel cache, at load 6), kept in warp's kernel cache
(``~/.cache/warp``); from a warm cache a process imports Newton and loads them in 2.5 s
(idle).  A state beyond :data:`MAXVAL` or not finite ends that
realisation (NaN from that step; its world is reset to rest so that it cannot
overflow the batch's arithmetic).
"""

from __future__ import annotations

import threading
from dataclasses import dataclass
from typing import Any

import mujoco
import numpy as np

from cip.engines.drake_plant import CIPGeometry, generalized_forces
from cip.engines.rigid_body import RigidBodyEngine, semi_implicit_rigid
from cip.engines.rollout import ModelRollout
from cip.names import cart_joint, hinge_joint

#: Relative L2 distance of the balancing error to the reduced model allowed at small
#: amplitude: the value of the other semi-implicit Euler engines with a rigid rod
#: (Pinocchio, DART, Bullet): the floor is the rigid body's cart reaction m/M (at most
#: 3.5e-3 over 10 s), every control one step late gives at least 6.2e-3; float32
#: rounding adds about 1e-6.
TRAJECTORY_TOLERANCE = 5e-3

#: The largest magnitude of a joint coordinate or velocity the step accepts (MuJoCo's
#: ``mjMAXVAL``); beyond it, or not finite, a realisation ends (NaN from that step).
MAXVAL = 1e10

#: The warp device the engine runs on (warp's CPU device: the engine's kernels are
#: compiled for the CPU; a CUDA device would run the same code).
DEVICE = "cpu"

#: Serialises the construction of Newton models and solvers: warp builds a kernel
#: module on its first launch, which is not thread-safe (``cip.engines.warp_batch``).
_LOCK = threading.Lock()


def _newton():
    """Import Newton, with warp's informational log (its banner, module loads) off."""
    import warp as wp

    if wp.config.log_level < wp.LOG_WARNING:
        wp.config.log_level = wp.LOG_WARNING
    import newton

    return newton


@dataclass
class NewtonCIP:
    """A finalised Newton model of ``n_worlds`` copies of the CIP.

    Its ``joint_q`` and ``joint_qd`` are (n_worlds, C, 2) arrays, world by world, with
    (cart x, hinge theta) per controller (:func:`build_model` checks the layout), and
    ``SolverFeatherstone.H`` holds the articulations' 2 x 2 inertia blocks in that order.
    """

    model: Any
    geometry: CIPGeometry
    n_worlds: int


def build_model(g: CIPGeometry, n_worlds: int) -> NewtonCIP:
    """The Newton model of ``n_worlds`` copies of the CIP described by ``g`` (module docstring)."""
    newton = _newton()
    import warp as wp

    one = newton.ModelBuilder(up_axis=newton.Axis.Z, gravity=g.gravity)
    free = {"armature": 0.0, "damping": 0.0, "stiffness": 0.0, "limit_ke": 0.0, "limit_kd": 0.0}
    joints = []
    for i in range(g.n_controllers):
        M, m, L = g.cart_mass[i], g.bob_mass[i], g.pendulum_length[i]
        rail = wp.transform_identity()  # at world x = 0, whatever cart_x0 (docstring)
        cart = one.add_link(xform=rail, mass=M, inertia=wp.mat33(*(M * np.eye(3)).ravel()))
        pend = one.add_link(
            xform=rail, mass=m, com=(0.0, 0.0, L),
            inertia=wp.mat33(*np.diag(g.bob_inertia[i]).ravel()),
        )  # fmt: skip
        jx = one.add_joint_prismatic(
            -1, cart, parent_xform=rail, axis=(1.0, 0.0, 0.0), label=cart_joint(i + 1), **free
        )
        jt = one.add_joint_revolute(
            cart, pend, axis=(0.0, 1.0, 0.0), label=hinge_joint(i + 1), **free
        )
        one.add_articulation([jx, jt])
        joints.append((jx, jt))
    batch = newton.ModelBuilder(up_axis=newton.Axis.Z, gravity=g.gravity)
    batch.replicate(one, n_worlds)
    model = batch.finalize(device=DEVICE, skip_validation_inertia=True)
    nj = len(one.joint_type)
    idx = np.array([[[w * nj + j for j in pair] for pair in joints] for w in range(n_worlds)])
    q, v = model.joint_q_start.numpy()[idx], model.joint_qd_start.numpy()[idx]
    every = np.arange(q.size).reshape(q.shape)
    if not (np.array_equal(q, every) and np.array_equal(v, every)):
        raise RuntimeError("Newton laid out the CIP's joint coordinates other than world by world")
    return NewtonCIP(model=model, geometry=g, n_worlds=n_worlds)


class NewtonRollout(ModelRollout):
    """:class:`cip.runner.RolloutBackend` stepping the CIP with Newton's Featherstone
    solver on warp's CPU device (module docstring).

    Parameters
    ----------
    model : the compiled MuJoCo CIP (:func:`cip.model.build`): the source of every
        physical parameter, the time step (``model.opt.timestep``) and the state layout.
    n_realizations : number of realisations: the Newton worlds of one batch (a call with
        another count builds a batch of that size).
    threads : ignored: the engine's ``max_threads`` is 1, every realisation is a world of
        the one batch that each kernel launch steps.
    """

    def __init__(self, model: mujoco.MjModel, n_realizations: int, threads: int) -> None:
        super().__init__(model)
        self.newton = _newton()
        g = self.geometry
        self.nc = g.n_controllers
        # per controller (x, theta) in mjSTATE_FULLPHYSICS
        # (C, 2) per controller: (cart, hinge) position and velocity columns
        self.mj_qc = np.stack([self.mj_x, self.mj_theta], axis=1)
        self.mj_vc = np.stack([self.mj_xdot, self.mj_omega], axis=1)
        self.length = np.array(g.pendulum_length)
        self.x0 = np.array(g.cart_x0)
        self.rod = g.rod_length
        self._batch(n_realizations)

    def _batch(self, n_worlds: int) -> None:
        """Build the Newton model, solver, states and control of ``n_worlds`` worlds."""
        with _LOCK:
            c = self.cip = build_model(self.geometry, n_worlds)
            self.solver = self.newton.solvers.SolverFeatherstone(c.model, angular_damping=0.0)
            self.states = [c.model.state(), c.model.state()]
            self.control = c.model.control()
        h = self.solver.H.numpy()
        if h.size != 4 * c.model.articulation_count:  # 2 x 2 blocks, one per articulation
            raise RuntimeError(f"SolverFeatherstone.H has {h.size} entries, expected 2 x 2 blocks")

    def _project(self, q: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(q+, v+): Newton's free step-end velocities ``v`` (R, 2, 2) projected onto
        J v+ = -g(q) / dt at the step's start positions ``q`` (module docstring)."""
        L, dt = self.length, self.dt
        sin, cos = np.sin(q[..., 1]), np.cos(q[..., 1])  # (R, 2)
        px = self.x0 + q[..., 0] + L * sin
        pz = L * cos
        dx, dz = px[:, 0] - px[:, 1], pz[:, 0] - pz[:, 1]
        dist = np.sqrt(dx * dx + dz * dz)
        nx, nz = dx / dist, dz / dist
        sign = np.array([1.0, -1.0])
        jac = np.empty_like(q)  # dg/dq: +-(n . dp_tip/dx, n . dp_tip/dtheta)
        jac[..., 0] = sign * nx[:, None]
        jac[..., 1] = sign * L * (nx[:, None] * cos - nz[:, None] * sin)
        h = self.solver.H.numpy().reshape(-1, 2, 2, 2).astype(np.float64)  # (R, C, 2, 2)
        det = h[..., 0, 0] * h[..., 1, 1] - h[..., 0, 1] * h[..., 1, 0]
        w = np.empty_like(q)  # H^-1 J^T, block by block
        w[..., 0] = (h[..., 1, 1] * jac[..., 0] - h[..., 0, 1] * jac[..., 1]) / det
        w[..., 1] = (h[..., 0, 0] * jac[..., 1] - h[..., 1, 0] * jac[..., 0]) / det
        jv = jac[:, 0, 0] * v[:, 0, 0] + jac[:, 0, 1] * v[:, 0, 1]
        jv = jv + jac[:, 1, 0] * v[:, 1, 0] + jac[:, 1, 1] * v[:, 1, 1]
        jw = jac[:, 0, 0] * w[:, 0, 0] + jac[:, 0, 1] * w[:, 0, 1]
        jw = jw + jac[:, 1, 0] * w[:, 1, 0] + jac[:, 1, 1] * w[:, 1, 1]
        lam = -(jv + (dist - self.rod) / dt) / jw
        v_new = v + lam[:, None, None] * w
        return q + dt * v_new, v_new

    def __call__(self, state: np.ndarray, ctrl: np.ndarray, out: np.ndarray) -> None:
        R, n = ctrl.shape[:2]
        if R != self.cip.n_worlds:
            self._batch(R)
        g, dt, shape = self.geometry, self.dt, (R, self.nc, 2)
        u = self.begin(state, ctrl, out)  # (R, n, C) cart forces, N
        # (R, C, 2) views of warp's CPU arrays: (x, theta) and their rates per controller
        (q0, v0), (q1, v1) = ((s.joint_q.numpy().reshape(shape), s.joint_qd.numpy().reshape(shape))
                              for s in self.states)  # fmt: skip
        joint_f = self.control.joint_f.numpy().reshape(shape)
        q_in, v_in = state[:, self.mj_qc], state[:, self.mj_vc]
        alive = np.isfinite(q_in).all(axis=(1, 2)) & np.isfinite(v_in).all(axis=(1, 2))
        out[~alive, :, 1:] = np.nan
        q0[:] = np.where(alive[:, None, None], q_in, 0.0)  # a dead world rests
        v0[:] = np.where(alive[:, None, None], v_in, 0.0)
        s0, s1 = self.states
        for k in range(n):
            q, v = q0.astype(np.float64), v0.astype(np.float64)
            f_cart, tau = generalized_forces(g, q[..., 1], v[..., 0], v[..., 1], u[:, k])
            joint_f[..., 0] = np.where(alive[:, None], f_cart, 0.0)
            joint_f[..., 1] = np.where(alive[:, None], tau, 0.0)
            self.solver.step(s0, s1, self.control, None, dt)
            if self.rod is not None:
                q1[:], v1[:] = self._project(q, v1.astype(np.float64))
            ok = (np.abs(q1) < MAXVAL).all(axis=(1, 2)) & (np.abs(v1) < MAXVAL).all(axis=(1, 2))
            ended = alive & ~ok
            if ended.any():  # NaN from here on: the drivers read it as divergence
                self._failed += int(ended.sum())
                out[ended, k:, 1:] = np.nan
                alive &= ok
                q1[ended], v1[ended] = 0.0, 0.0
            live = out[:, k]
            live[:, self.mj_qc] = np.where(alive[:, None, None], q1, live[:, self.mj_qc])
            live[:, self.mj_vc] = np.where(alive[:, None, None], v1, live[:, self.mj_vc])
            s0, s1, q0, v0, q1, v1 = s1, s0, q1, v1, q0, v0
        self.states = [s0, s1]


ENGINE = RigidBodyEngine(
    name="newton",
    capabilities=semi_implicit_rigid(
        "Newton",
        "Newton Featherstone",
        TRAJECTORY_TOLERANCE,
        precision="float32",
        kernels="warp",
        batch=True,  # 0.39 / 0.40 / 0.50 ms a step for 1 / 8 / 64 worlds (module docstring)
    ),
    backend=lambda: NewtonRollout,
    requires=("newton", "warp"),
    max_threads=1,  # one batch of worlds per call: every realisation in each launch
    integrators=(),
    notes="Newton (warp, CPU device, float32) SolverFeatherstone: CRBA + semi-implicit Euler "
    "over a batch of worlds, explicit dampers as joint_f; rod as a rigid distance constraint "
    "(cipval's velocity projection with Featherstone's joint-space inertia)",
)
