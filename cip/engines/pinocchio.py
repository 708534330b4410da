"""Pinocchio as a registered engine: the CIP as a Pinocchio kinematic tree.

Every physical number is read from the compiled MuJoCo model
(:func:`cip.engines.drake_plant.geometry_from_mujoco`), and the model is built with
Pinocchio's API (no URDF or MJCF parser); per controller i:

* cart: a ``JointModelPX`` (prismatic along world +x) ``x_M<i>`` on the universe,
  placed at the cart's reference position (x = -+l/2 in the coupled model), so that
  the coordinate is the MJCF ``qpos`` of the slide (m), carrying the cart's mass M
  (kg);
* pendulum: a ``JointModelRY`` (revolute about +y: theta > 0 tilts the tip to +x, as
  in MuJoCo) ``theta_<i>`` at the cart's origin, carrying the massless pole's bob,
  ``pin.Inertia(m, (0, 0, L), I)`` with the MJCF's central inertia I; an operational
  frame ``tip_<i>`` at (0, 0, L) in the pendulum frame (the MJCF's tip site);
* gravity: the MJCF's gravity vector (m/s^2).

The step (one call of :meth:`PinocchioRollout._step` per dt): the control and the
MJCF's damping are generalised forces evaluated at the state at the start of the
step, explicit as in MuJoCo's ``Euler``: the motor gear u on the cart, the cart
damping -c_cart v_M, and the tip damping F_t = -c_tip v_tip,x along world x at the
tip, mapped through the tip frame's Jacobian (``LOCAL_WORLD_ALIGNED``), Q = J_x^T F_t
(so Q_x = F_t and Q_theta = F_t L cos(theta), v_tip,x = J_x v).  The unconstrained
acceleration is Pinocchio's articulated-body algorithm (``pin.aba``), then
semi-implicit Euler: v+ = v + dt a, q+ = q + dt v+ (``pin.integrate``).  The single
model's step is therefore MuJoCo's ``Euler`` step (same scheme, same explicit
forces): against ``mujoco.rollout`` on the single model (4 band-limited open-loop
forces, 1 s, |e| up to 6.7e-4 m) the relative L2 distance of (qpos, qvel) is 1.2e-16,
round-off.  On the coupled model it is 5.5e-7: MuJoCo's soft rod (solref) against
this rigid one, a model difference.

The rod (coupled model) is a **rigid** distance constraint between the tips,
g(q) = |p_tip,1 - p_tip,2| - l, imposed at the velocity level on the step's end
velocity with full position correction: v+ = v_free + M^-1 J^T lambda with
J v+ = -g(q) / dt, J = dg/dq (1 x nv, from the two tip frames' Jacobians), M the
joint-space inertia (its inverse from ``pin.computeMinverse``),
lambda = -(J v_free + g / dt) / (J M^-1 J^T): the impulse that projects v_free, in
the metric of M, onto the velocities that close the rod after the step to first order
(Moreau's time stepping of a bilateral constraint).  An acceleration-level solve of
J a = -J' v before the projection would not change v+ (the projection of any
v_free + M^-1 J^T mu is the same), so it is not done.  The stretch left after a
step is the rod's curvature term, O(dt^2 |v|^2 / l), corrected on the next step:
at most 3.2e-11 m over 2 s of forced motion up to 0.12 rad.

Validation: no exact twin of cipval's (``capabilities.twin`` None) is claimed, so
cipval judges the engine by time-step refinement
(:mod:`validation.checks.refinement`): the open-loop trajectories at dt = h .. h/8
converge, order 1, to the exact zero-order-hold solution of the linearised rigid
body (the rod rigid).  Measured (pin 4.1.0, ``refinement_check``, seed 1): E0 9.6e-9
(interval up to 8.8e-8) and observed order 1.002 on the single model, E0 1.5e-8 (up to
1.4e-7) and order 1.002 on the coupled one (floor 1e-6, least order 0.7); a 1e-3
error of the tip mass (``make_fault("mass_ratio", 1e-3)``) moves E0 to 1.5e-4 / 1.0e-4
and fails.  Against the Euler twin of the model file (not its tier: ``twin.*`` n/a) the
single model is at 1.1e-11, the coupled at 1.3e-7 (the soft rod again).

The state passed in at each chunk is read afresh (positions and velocities from
the ``mjSTATE_FULLPHYSICS`` vector; nothing is carried between calls), each
realisation is stepped on its own (one ``pin.Data``, reused: Pinocchio's algorithms
keep nothing from one call to the next), so the numbers of a realisation do not
depend on its batch.  The step is a Python loop of Pinocchio calls holding the GIL:
the engine's ``threads`` are worker processes (:class:`cip.workers.ProcessBlocks`).
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
from cip.names import cart_joint, hinge_joint, tip_site

#: Relative L2 distance of the balancing error to the reduced model allowed at 1e-6 m:
#: the value of the other semi-implicit Euler engines with a rigid rod (Bullet): the
#: floor is the rigid body's cart reaction m/M (at most 3.5e-3 over 10 s), every
#: control one step late gives at least 6.2e-3.
TRAJECTORY_TOLERANCE = 5e-3


def _pinocchio():
    import pinocchio

    return pinocchio


@dataclass
class PinocchioCIP:
    """A Pinocchio model of the CIP and where its coordinates live.

    ``q_x``, ``q_theta`` index the configuration, ``v_x``, ``v_theta`` the
    velocity (one entry per controller); ``tips`` are the tip frames' ids.
    """

    model: Any
    geometry: CIPGeometry
    q_x: np.ndarray
    q_theta: np.ndarray
    v_x: np.ndarray
    v_theta: np.ndarray
    tips: tuple[int, ...]


def build_model(g: CIPGeometry) -> PinocchioCIP:
    """The Pinocchio model of the CIP described by ``g`` (module docstring)."""
    pin = _pinocchio()
    model = pin.Model()
    model.name = "cip"
    model.gravity = pin.Motion(np.array(g.gravity), np.zeros(3))
    eye = np.eye(3)
    joints, tips = [], []
    for i in range(g.n_controllers):
        M, m, L = g.cart_mass[i], g.bob_mass[i], g.pendulum_length[i]
        rail = pin.SE3(eye, np.array([g.cart_x0[i], 0.0, 0.0]))
        jx = model.addJoint(0, pin.JointModelPX(), rail, cart_joint(i + 1))
        # the cart's rotational inertia is never excited (it only translates)
        model.appendBodyToJoint(jx, pin.Inertia(M, np.zeros(3), M * eye), pin.SE3.Identity())
        jt = model.addJoint(jx, pin.JointModelRY(), pin.SE3.Identity(), hinge_joint(i + 1))
        bob = pin.Inertia(m, np.array([0.0, 0.0, L]), np.diag(g.bob_inertia[i]))
        model.appendBodyToJoint(jt, bob, pin.SE3.Identity())
        tip = pin.Frame(
            tip_site(i + 1), jt, pin.SE3(eye, np.array([0.0, 0.0, L])), pin.FrameType.OP_FRAME
        )
        tips.append(model.addFrame(tip))
        joints.append((jx, jt))
    # no joint damping, friction or armature of Pinocchio's own: the MJCF's dampers are
    # explicit generalised forces (module docstring)
    model.damping[:] = 0.0
    model.armature[:] = 0.0
    jm = model.joints
    return PinocchioCIP(
        model=model,
        geometry=g,
        q_x=np.array([jm[jx].idx_q for jx, _ in joints]),
        q_theta=np.array([jm[jt].idx_q for _, jt in joints]),
        v_x=np.array([jm[jx].idx_v for jx, _ in joints]),
        v_theta=np.array([jm[jt].idx_v for _, jt in joints]),
        tips=tuple(tips),
    )


class PinocchioRollout(ModelRollout):
    """:class:`cip.runner.RolloutBackend` stepping the CIP with Pinocchio (module docstring), one
    realisation after another in a loop that holds the GIL (see ``ModelRollout``)."""

    modules = ("pinocchio",)

    def __init__(self, model: mujoco.MjModel, n_realizations: int, threads: int) -> None:
        super().__init__(model)
        self.pin = _pinocchio()
        g = self.geometry
        c = self.cip = build_model(g)
        self.model = c.model
        self.data = c.model.createData()
        self.nq, self.nv = c.model.nq, c.model.nv
        self.pin_q = np.r_[c.q_x, c.q_theta]
        self.pin_v = np.r_[c.v_x, c.v_theta]
        self.c_tip = np.array(g.tip_damping)
        self.c_cart = np.array(g.cart_damping)
        self.rod = g.rod_length
        self.frame = self.pin.ReferenceFrame.LOCAL_WORLD_ALIGNED
        self.lower = np.tril_indices(self.nv, -1)

    def _step(self, q: np.ndarray, v: np.ndarray, f_cart: np.ndarray):
        """(q+, v+) after one step of dt from (q, v) with motor forces ``f_cart`` (C,) (N)."""
        pin, model, data, c, dt = self.pin, self.model, self.data, self.cip, self.dt
        pin.computeJointJacobians(model, data, q)  # forward kinematics and joint Jacobians
        pin.updateFramePlacements(model, data)
        jac = [pin.getFrameJacobian(model, data, f, self.frame)[:3] for f in c.tips]
        tau = np.zeros(self.nv)
        tau[c.v_x] = f_cart - self.c_cart * v[c.v_x]
        for i, j in enumerate(jac):
            jx = j[0]  # the tip's world-x row: v_tip,x = jx v
            tau += jx * (-self.c_tip[i] * (jx @ v))  # -c_tip v_tip,x along world x at the tip
        v_new = v + dt * pin.aba(model, data, q, v, tau)
        if self.rod is not None:
            d = data.oMf[c.tips[0]].translation - data.oMf[c.tips[1]].translation
            dist = math.sqrt(d @ d)
            jr = (d / dist) @ (jac[0] - jac[1])  # dg/dq (1 x nv)
            minv = pin.computeMinverse(model, data, q)
            minv[self.lower] = minv.T[self.lower]  # (bindings that fill the upper triangle only)
            w = minv @ jr  # M^-1 J^T
            lam = -(jr @ v_new + (dist - self.rod) / dt) / (jr @ w)
            v_new = v_new + lam * w
        return pin.integrate(model, q, dt * v_new), v_new

    def __call__(self, state: np.ndarray, ctrl: np.ndarray, out: np.ndarray) -> None:
        R, n = ctrl.shape[:2]
        u = self.begin(state, ctrl, out)  # (R, n, C) cart forces, N
        qs, vs = np.empty((n, self.nq)), np.empty((n, self.nv))
        for r in range(R):
            q, v = np.zeros(self.nq), np.zeros(self.nv)
            q[self.pin_q] = state[r, self.mj_q]
            v[self.pin_v] = state[r, self.mj_v]
            if not (np.isfinite(q).all() and np.isfinite(v).all()):
                out[r, :, 1:] = np.nan
                continue
            for k in range(n):
                q, v = self._step(q, v, u[r, k])
                qs[k], vs[k] = q, v
            out[r, :, self.mj_q] = qs[:, self.pin_q].T
            out[r, :, self.mj_v] = vs[:, self.pin_v].T
            # a state that overflowed propagates as inf/NaN through the following steps;
            # the drivers read NaN as divergence
            bad = ~(np.isfinite(qs).all(axis=1) & np.isfinite(vs).all(axis=1))
            if bad.any():
                self.diverged(out, r, int(np.argmax(bad)))


ENGINE = RigidBodyEngine(
    name="pinocchio",
    capabilities=semi_implicit_rigid("Pinocchio", "ABA", TRAJECTORY_TOLERANCE),
    backend=lambda: PinocchioRollout,
    requires=("pinocchio",),
    integrators=(),
    backend_workers=True,  # threads are worker processes (the step holds the GIL)
    notes="Pinocchio kinematic tree, ABA + semi-implicit Euler, explicit dampers; rod as a "
    "rigid distance constraint (velocity projection, full position correction)",
)
