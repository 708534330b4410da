"""DART as a registered engine: the CIP as DART skeletons (dartpy).

Every physical number is read from the compiled MuJoCo model
(:func:`cip.engines.drake_plant.geometry_from_mujoco`), and the model is built with
dartpy's API (no URDF, SDF or MJCF parser); per controller i a skeleton ``cip_<i>``:

* cart: a ``PrismaticJoint`` (axis world +x) ``x_M<i>`` on the world, placed at the
  cart's reference position (x = +-l/2 in the coupled model), so that the coordinate
  is the MJCF ``qpos`` of the slide (m), its body carrying the cart's mass M (kg);
* pendulum: a ``RevoluteJoint`` (axis +y: theta > 0 tilts the tip to +x, as in
  MuJoCo) ``theta_<i>`` at the cart's origin, its body carrying the massless pole's
  bob: mass m at the local centre of mass (0, 0, L) with the MJCF's central inertia;
  the tip (the MJCF's tip site) is the point (0, 0, L) of that body;
* gravity: the MJCF's gravity vector (m/s^2); no joint damping, spring, friction,
  limits or shapes of DART's own (nothing collides: there is no collision geometry).

The step (one call of :meth:`DartRollout._step` per dt), per skeleton: the control and
the MJCF's damping are evaluated at the state at the start of the step, explicit as in
MuJoCo's ``Euler``: the motor gear u and the cart damping -c_cart v_M as the cart
joint's generalised force (``setForce``), and the tip damping F_t = -c_tip v_tip,x
(v_tip,x the tip's world-x velocity, ``BodyNode.getCOMLinearVelocity``: the tip is the
bob's centre of mass) as an external force along world x at the tip (``addExtForce``,
cleared and set again at every step), which DART's dynamics map to Q = J_tip,x^T F_t
(Q_x = F_t, Q_theta = F_t L cos(theta)).  Then DART's own semi-implicit Euler, the
sequence of ``World::step`` without its constraint solver
(``Skeleton::computeForwardDynamics``: the articulated-body algorithm;
``integrateVelocities``: v+ = v + dt a; ``integratePositions``: q+ = q + dt v+; DART
6.x ``dart/simulation/World.cpp`` and ``GenericJoint::integrateVelocities`` /
``integratePositions``).  The skeletons are stepped directly, not in a
``dart.simulation.World``: the world's step would add only its constraint solver
(collision detection, contacts, joint limits), which this model does not use, so no
contact or collision can enter.  The single model's step is therefore MuJoCo's
``Euler`` step (same scheme, same explicit forces): against ``mujoco.rollout`` on the
single model (4 band-limited open-loop forces, 1 s, tilted 0.01 rad at the start,
|e| up to 6.9e-3 m) the relative L2 distance of (qpos, qvel) is 6.1e-17, round-off.
On the coupled model (both pendulums tilted 0.01 rad) it is 1.8e-7: MuJoCo's soft rod
(solref) against this rigid one, a model difference; to the Pinocchio engine (the same
scheme and projection) 1.4e-12 (the rod's g / dt amplifies the rounding of the tips'
positions).

The rod (coupled model) is a **rigid** distance constraint between the tips,
g(q) = |p_tip,1 - p_tip,2| - l.  dartpy 6.20 has no distance constraint between two
bodies (its joint constraints, ``BallJointConstraint``, ``RevoluteJointConstraint``,
``WeldJointConstraint`` ..., pin points or frames together; a rod body closed by two
ball-joint constraints would add the rod's mass and go through the world's LCP
solver), so the rod is cipval's velocity projection on DART's bodies, not a DART
constraint: after DART's unconstrained velocity step, v+ = v_free + M^-1 J^T lambda
with J v+ = -g(q) / dt, J = dg/dq (1 x nv, from the pendulum bodies'
``getLinearJacobian`` at the tip, at q), M^-1 the skeletons' inverse mass matrices
(``getInvMassMatrix``: block diagonal, a skeleton per controller),
lambda = -(J v_free + g / dt) / (J M^-1 J^T), set as the skeletons' velocities before
DART integrates the positions with them (as the Pinocchio engine: Moreau's time
stepping of a bilateral constraint, full position correction).  The stretch left
after a step is the rod's curvature term, O(dt^2 |v|^2 / l), corrected on the next
step: at most 5.0e-9 m over 2 s of band-limited forcing up to 0.12 rad (the Pinocchio
engine's on the same forces, to 2e-16 m); in the contract's rod check, 3.7e-12 m.

Validation: no exact twin of cipval's (``capabilities.twin`` None) is claimed, so
cipval judges the engine by time-step refinement
(:mod:`validation.checks.refinement`): the open-loop trajectories at dt = h .. h/8
converge, order 1, to the exact zero-order-hold solution of the linearised rigid
body (the rod rigid).  Measured (dartpy 6.20.0, ``refinement_check``, seed 1): E0
9.6e-9 (interval up to 8.8e-8) and observed order 1.002 on the single model, E0
1.5e-8 (up to 1.4e-7) and order 1.002 on the coupled one (floor 1e-6, least order
0.7); a 1e-3 error of the tip mass (``make_fault("mass_ratio", 1e-3)``) moves E0 to
1.5e-4 / 1.0e-4 and fails.  Against the Euler twin of the model file (not its tier:
``twin.*`` n/a) the single model is at 1.1e-11, the coupled at 1.3e-7 (the soft rod).

The state passed in at each chunk is read afresh (positions and velocities from the
``mjSTATE_FULLPHYSICS`` vector, set on the skeletons; the joint forces are set and the
external forces cleared at every step: nothing is carried between realisations or
calls), each realisation is stepped on its own, so the numbers of a realisation do
not depend on its batch (bit-identical for 1, 2 and 3 worker processes).  A state or
force beyond :data:`MAXVAL` stops the realisation (NaN from that step).  The step is a
Python loop of dartpy calls holding the GIL: the engine's ``threads`` are worker
processes (:class:`cip.workers.ProcessBlocks`).  Measured (one process, 4 x 2 s,
best of 3, a loaded 2-core machine): 4.3e4 steps/s on the single model, 1.1e4 on the
coupled one (the Pinocchio engine: 3.3e4, 1.0e4).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import mujoco
import numpy as np

from cip.engines.drake_plant import CIPGeometry
from cip.engines.rigid_body import RigidBodyEngine, semi_implicit_rigid
from cip.engines.rollout import ModelRollout
from cip.names import cart_joint, hinge_joint

#: Relative L2 distance of the balancing error to the reduced model allowed at 1e-6 m:
#: the value of the other semi-implicit Euler engines with a rigid rod (Bullet,
#: Pinocchio): the floor is the rigid body's cart reaction m/M (at most 3.5e-3 over
#: 10 s), every control one step late gives at least 6.2e-3.
TRAJECTORY_TOLERANCE = 5e-3


#: The largest magnitude of a state coordinate or force that the step accepts:
#: MuJoCo's ``mjMAXVAL`` (its bad qpos / qvel / qacc warning).  DART 6.20 replaces a
#: non-finite acceleration by zero and a non-finite transform by the identity (with a
#: warning on stderr) rather than propagating it, so a realisation is stopped at the
#: first state beyond this bound (NaN from that step, as the other engines' overflow)
#: before DART can see an overflow.
MAXVAL = 1e10


def _dartpy():
    import dartpy

    return dartpy


@dataclass
class DartCIP:
    """DART skeletons of the CIP (one per controller) and the bodies the step uses.

    Each skeleton's generalised coordinates are (x_i, theta_i), in that order;
    ``tips`` are the tip points in the pendulum bodies' frames.
    """

    skeletons: tuple[Any, ...]
    carts: tuple[Any, ...]
    pendulums: tuple[Any, ...]
    tips: tuple[np.ndarray, ...]
    geometry: CIPGeometry


def build_model(g: CIPGeometry) -> DartCIP:
    """The DART skeletons of the CIP described by ``g`` (module docstring)."""
    dart = _dartpy()
    skeletons, carts, pendulums, tips = [], [], [], []
    for i in range(g.n_controllers):
        M, m, L = g.cart_mass[i], g.bob_mass[i], g.pendulum_length[i]
        skel = dart.dynamics.Skeleton(f"cip_{i + 1}")
        jx, cart = skel.createPrismaticJointAndBodyNodePair()
        jx.setName(cart_joint(i + 1))
        jx.setAxis(np.array([1.0, 0.0, 0.0]))
        rail = dart.math.Isometry3()
        rail.set_translation(np.array([g.cart_x0[i], 0.0, 0.0]))
        jx.setTransformFromParentBodyNode(rail)
        cart.setMass(M)
        cart.setMomentOfInertia(M, M, M)  # never excited: the cart only translates
        jt, pend = skel.createRevoluteJointAndBodyNodePair(cart)
        jt.setName(hinge_joint(i + 1))
        jt.setAxis(np.array([0.0, 1.0, 0.0]))
        tip = np.array([0.0, 0.0, L])
        pend.setMass(m)
        pend.setLocalCOM(tip)
        pend.setMomentOfInertia(*g.bob_inertia[i])
        for j in (jx, jt):  # no damper, spring or friction of DART's own (docstring)
            j.setDampingCoefficient(0, 0.0)
            j.setSpringStiffness(0, 0.0)
            j.setCoulombFriction(0, 0.0)
            j.setLimitEnforcement(False)
        skel.setGravity(np.array(g.gravity))
        skel.setTimeStep(g.timestep)
        skeletons.append(skel)
        carts.append(cart)
        pendulums.append(pend)
        tips.append(tip)
    return DartCIP(
        skeletons=tuple(skeletons),
        carts=tuple(carts),
        pendulums=tuple(pendulums),
        tips=tuple(tips),
        geometry=g,
    )


def _block(n: list[float], jac: list[list[float]], minv: list[list[float]], sign: float):
    """(j, w) of one skeleton's 2 dofs: j = sign n^T J (3 x 2 Jacobian), w = M^-1 j."""
    j0 = sign * (n[0] * jac[0][0] + n[1] * jac[1][0] + n[2] * jac[2][0])
    j1 = sign * (n[0] * jac[0][1] + n[1] * jac[1][1] + n[2] * jac[2][1])
    return (j0, j1), (minv[0][0] * j0 + minv[0][1] * j1, minv[1][0] * j0 + minv[1][1] * j1)


class DartRollout(ModelRollout):
    """:class:`cip.runner.RolloutBackend` stepping the CIP with DART (module docstring), one
    realisation after another in a loop that holds the GIL (see ``ModelRollout``)."""

    modules = ("dartpy",)

    def __init__(self, model: mujoco.MjModel, n_realizations: int, threads: int) -> None:
        super().__init__(model)
        g = self.geometry
        self.cip = build_model(g)
        self.nc = g.n_controllers
        # per controller (x, theta) in mjSTATE_FULLPHYSICS
        # (C, 2) per controller: (cart, hinge) position and velocity columns
        self.mj_qc = np.stack([self.mj_x, self.mj_theta], axis=1)
        self.mj_vc = np.stack([self.mj_xdot, self.mj_omega], axis=1)
        self.c_tip = list(g.tip_damping)
        self.c_cart = list(g.cart_damping)
        self.rod = g.rod_length
        self._force = np.zeros(3)  # the tip damper's world force (N), set each step

    def _step(self, f_cart: list[float]) -> None:
        """One step of dt of the skeletons' state with motor forces ``f_cart`` (C) (N)."""
        c, dt, force = self.cip, self.dt, self._force
        for skel, pend, tip, f, c_tip, c_cart in zip(
            c.skeletons, c.pendulums, c.tips, f_cart, self.c_tip, self.c_cart, strict=True
        ):
            # the tip's world-x velocity at the start of the step (the tip is the bob's
            # centre of mass: geometry_from_mujoco checks it)
            force[0] = -c_tip * pend.getCOMLinearVelocity()[0]
            skel.setForce(0, f - c_cart * skel.getVelocity(0))
            skel.clearExternalForces()
            pend.addExtForce(force, tip, False, True)  # world x, at the tip (body frame)
            skel.computeForwardDynamics()
            skel.integrateVelocities(dt)
        if self.rod is not None:
            self._project()
        for skel in c.skeletons:
            skel.integratePositions(dt)

    def _project(self) -> None:
        """Project the free velocities onto J v+ = -g(q) / dt (module docstring).

        In Python floats: the operands are 2- and 3-vectors, where each NumPy call
        would cost more than the arithmetic."""
        c = self.cip
        (s1, s2), (b1, b2), (t1, t2) = c.skeletons, c.pendulums, c.tips
        p1, p2 = b1.getCOM().tolist(), b2.getCOM().tolist()  # the tips (bobs' centres)
        d = [a - b for a, b in zip(p1, p2, strict=True)]
        dist = math.sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2])
        n = [x / dist for x in d]
        # dg/dq and M^-1 dg/dq^T block by block (skeleton i's dofs x_i, theta_i):
        # +-n . J_tip,i
        j1, w1 = _block(n, b1.getLinearJacobian(t1).tolist(), s1.getInvMassMatrix().tolist(), 1.0)
        j2, w2 = _block(n, b2.getLinearJacobian(t2).tolist(), s2.getInvMassMatrix().tolist(), -1.0)
        (v10, v11), (v20, v21) = s1.getVelocities().tolist(), s2.getVelocities().tolist()
        jv = j1[0] * v10 + j1[1] * v11 + j2[0] * v20 + j2[1] * v21
        jw = j1[0] * w1[0] + j1[1] * w1[1] + j2[0] * w2[0] + j2[1] * w2[1]
        lam = -(jv + (dist - self.rod) / self.dt) / jw
        s1.setVelocity(0, v10 + lam * w1[0])
        s1.setVelocity(1, v11 + lam * w1[1])
        s2.setVelocity(0, v20 + lam * w2[0])
        s2.setVelocity(1, v21 + lam * w2[1])

    def __call__(self, state: np.ndarray, ctrl: np.ndarray, out: np.ndarray) -> None:
        R = ctrl.shape[0]
        u = self.begin(state, ctrl, out)  # (R, n, C) cart forces, N
        skels = self.cip.skeletons
        for r in range(R):
            q0, v0 = state[r, self.mj_qc], state[r, self.mj_vc]  # (C, 2) each
            if not (np.isfinite(q0).all() and np.isfinite(v0).all()):
                out[r, :, 1:] = np.nan
                continue
            for i, skel in enumerate(skels):
                skel.setPositions(q0[i])
                skel.setVelocities(v0[i])
            rows = []  # per step: (x_i, theta_i, xdot_i, thetadot_i) of each controller
            bad = None  # the first step whose state is not a number (MAXVAL)
            for f in u[r].tolist():
                if not all(abs(x) < MAXVAL for x in f):  # (NaN compares False)
                    bad = len(rows)
                    break
                self._step(f)
                row = [
                    (s.getPosition(0), s.getPosition(1), s.getVelocity(0), s.getVelocity(1))
                    for s in skels
                ]
                rows.append(row)
                if not all(abs(x) < MAXVAL for xs in row for x in xs):
                    bad = len(rows) - 1
                    break
            if rows:
                qv = np.array(rows)  # (k, C, 4)
                out[r, : len(rows)][:, self.mj_qc] = qv[..., :2]
                out[r, : len(rows)][:, self.mj_vc] = qv[..., 2:]
            if bad is not None:  # a state or force beyond MAXVAL: NaN from there
                self.diverged(out, r, bad)


ENGINE = RigidBodyEngine(
    name="dart",
    capabilities=semi_implicit_rigid("DART", "DART", TRAJECTORY_TOLERANCE),
    backend=lambda: DartRollout,
    requires=("dartpy",),
    integrators=(),
    backend_workers=True,  # threads are worker processes (the step holds the GIL)
    notes="DART skeletons (dartpy), ABA + DART's semi-implicit Euler, explicit dampers; rod "
    "as a rigid distance constraint (cipval's velocity projection on DART's bodies)",
)
