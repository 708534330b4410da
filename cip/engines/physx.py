"""NVIDIA PhysX (through SAPIEN 3) as a registered engine: the CIP as PhysX articulations.

DRAFT: the docstring is completed from the measurements below.
"""

from __future__ import annotations

import warnings
from typing import Any

import mujoco
import numpy as np

from cip.engines.drake_plant import CIPGeometry, geometry_from_mujoco
from cip.engines.rigid_body import RigidBodyEngine
from cip.names import cart_joint, hinge_joint
from cipcore.engine import Capabilities

#: Relative L2 distance of the balancing error to the reduced model allowed at 1e-6 m (the
#: value of the other semi-implicit Euler engines, Bullet and Pinocchio).
TRAJECTORY_TOLERANCE = 5e-3

#: PhysX's solver: TGS (temporal Gauss-Seidel) when True, PGS when False
TGS = True

#: a bound no CIP velocity reaches (m/s, rad/s): PhysX's velocity clamps switched off
UNBOUNDED = 1e30


def _sapien() -> Any:
    """Import SAPIEN without its renderer's start-up warning (no display, no Vulkan needed)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        import sapien

    return sapien


def _free(link: Any) -> None:
    """Switch off what PhysX adds to an articulation link by default: linear and angular
    damping (0.05 1/s each) and velocity clamps (10 m/s, 50 rad/s)."""
    link.linear_damping = 0.0
    link.angular_damping = 0.0
    link.max_linear_velocity = UNBOUNDED
    link.max_angular_velocity = UNBOUNDED
    link.disable_gravity = False


def _link(physx: Any, parent: Any, mass: float, inertia, com) -> Any:
    """An articulation link with the given mass, central principal inertia and centre of mass
    (explicit: no collision shape, so nothing is computed from geometry)."""
    link = physx.PhysxArticulationLinkComponent(parent)
    link.mass = float(mass)
    link.inertia = np.asarray(inertia, dtype=np.float32)
    link.cmass_local_pose = com
    _free(link)
    return link


def _free_joint(joint: Any, kind: str, name: str, in_parent: Any, in_child: Any) -> None:
    """A joint without PhysX's defaults: friction coefficient 0 (default 0.05), no velocity
    clamp (default 100), no limits (default [0, 0]: locked), no drive."""
    joint.type = kind
    joint.name = name
    joint.pose_in_parent = in_parent
    joint.pose_in_child = in_child
    joint.friction = 0.0
    joint.max_velocity = UNBOUNDED
    joint.limit = np.array([[-np.inf, np.inf]], dtype=np.float32)
    joint.set_drive_property(0.0, 0.0)
    joint.armature = np.zeros(1, dtype=np.float32)


class PhysxWorld:
    """A PhysX CPU system holding ``n_realizations`` copies of the CIP of ``g`` (one
    articulation per balancer, the rod a distance joint between the tips), stepping dt."""

    def __init__(self, g: CIPGeometry, dt: float, n_realizations: int) -> None:
        sapien = _sapien()
        physx = sapien.physx
        Pose = sapien.Pose
        self.geometry = g
        saved = physx.get_scene_config()
        try:
            physx.set_scene_config(
                gravity=np.array(g.gravity, dtype=np.float32), enable_tgs=TGS, cpu_workers=0
            )
            self.system = physx.PhysxCpuSystem()
        finally:
            physx.set_scene_config(saved)
        self.system.timestep = dt
        self.scene = sapien.pysapien.Scene([self.system])
        # the joint frames' x axis is the joint's axis: +x for the slide; for the hinge the
        # frame turned by +90 deg about z, so that its x is +y (theta > 0 tilts the tip to +x)
        hinge = Pose([0.0, 0.0, 0.0], [np.sqrt(0.5), 0.0, 0.0, np.sqrt(0.5)])
        self.articulations: list[Any] = []  # realisation r, balancer i at r * C + i
        self.rods: list[Any] = []
        C = g.n_controllers
        for _ in range(n_realizations):
            tips = []
            for i in range(C):
                M, m, L = g.cart_mass[i], g.bob_mass[i], g.pendulum_length[i]
                base = _link(physx, None, 1.0, (1.0, 1.0, 1.0), Pose())
                base.joint.type = "fixed"
                # the cart only translates: its rotational inertia is never excited
                cart = _link(physx, base, M, (M, M, M), Pose())
                _free_joint(cart.joint, "prismatic", cart_joint(i + 1),
                            Pose([g.cart_x0[i], 0.0, 0.0]), Pose())  # fmt: skip
                bob = _link(physx, cart, m, g.bob_inertia[i], Pose([0.0, 0.0, L]))
                _free_joint(bob.joint, "revolute_unwrapped", hinge_joint(i + 1), hinge, hinge)
                for link in (base, cart, bob):
                    entity = sapien.Entity()
                    entity.add_component(link)
                    self.scene.add_entity(entity)
                art = base.articulation
                art.sleep_threshold = 0.0  # never put to sleep (default 0.005: a CIP at rest)
                self.articulations.append(art)
                tips.append((bob, L))
            if g.rod_length is not None:
                (b1, l1), (b2, l2) = tips
                rod = physx.PhysxDistanceJointComponent(b2)
                rod.parent = b1
                rod.pose_in_parent = Pose([0.0, 0.0, l1])
                rod.pose_in_child = Pose([0.0, 0.0, l2])
                rod.set_limit(g.rod_length, g.rod_length, 0.0, 0.0)  # stiffness 0: hard
                b2.entity.add_component(rod)
                self.rods.append(rod)


class PhysxRollout:
    """:class:`cip.runner.RolloutBackend` stepping the CIP with PhysX (module docstring).

    Parameters
    ----------
    model : the compiled MuJoCo CIP (:func:`cip.model.build`): the source of every
        physical parameter, the time step (``model.opt.timestep``) and the state layout.
    n_realizations : number of realisations (one articulation each per balancer, all in
        one PhysX system).
    threads : ignored (the step is a Python loop holding the GIL): the engine's
        ``threads`` are worker processes (:class:`cip.workers.ProcessBlocks`).
    """

    @staticmethod
    def preload() -> None:
        """Import SAPIEN (:class:`cip.workers.ProcessBlocks` forks after)."""
        _sapien()

    def __init__(self, model: mujoco.MjModel, n_realizations: int, threads: int) -> None:
        g = self.geometry = geometry_from_mujoco(model)
        self.dt = float(model.opt.timestep)
        self.C = g.n_controllers
        self.world = PhysxWorld(g, self.dt, max(1, n_realizations))
        # mjSTATE_FULLPHYSICS: time, qpos (nq), qvel (nv), ...; per balancer (x, theta)
        self.mj_q = 1 + np.stack([g.qpos_x, g.qpos_theta], axis=1)  # (C, 2)
        self.mj_v = 1 + model.nq + np.stack([g.dof_x, g.dof_theta], axis=1)
        self.motor = np.array(g.motor_id)
        self.gear = np.array(g.motor_gear)
        self.c_tip = np.array(g.tip_damping)
        self.c_cart = np.array(g.cart_damping)
        self.length = np.array(g.pendulum_length)
        self._failed = 0

    def _ensure(self, R: int) -> None:
        if len(self.world.articulations) < R * self.C:
            self.world = PhysxWorld(self.geometry, self.dt, R)

    def __call__(self, state: np.ndarray, ctrl: np.ndarray, out: np.ndarray) -> None:
        R, n = ctrl.shape[:2]
        C = self.C
        self._ensure(R)
        arts = self.world.articulations[: R * C]
        out[...] = state[:, None, :]
        out[:, :, 0] = state[:, None, 0] + self.dt * np.arange(1, n + 1)
        u = ctrl[:, :, self.motor] * self.gear  # (R, n, C) cart forces, N
        q = state[:, self.mj_q]  # (R, C, 2): x, theta
        v = state[:, self.mj_v]
        live = np.isfinite(q).all(axis=(1, 2)) & np.isfinite(v).all(axis=(1, 2))
        q32 = np.where(live[:, None, None], q, 0.0).astype(np.float32).reshape(R * C, 2)
        v32 = np.where(live[:, None, None], v, 0.0).astype(np.float32).reshape(R * C, 2)
        for a, qa, va in zip(arts, q32, v32, strict=True):
            a.qpos = qa
            a.qvel = va
        qs = np.empty((n, R * C, 2))
        vs = np.empty((n, R * C, 2))
        qf = np.empty((R * C, 2), dtype=np.float32)
        qk = q32.astype(np.float64)
        vk = v32.astype(np.float64)
        system = self.world.system
        for k in range(n):
            # the forces at the state of the step's start, held over the step (explicit)
            x_dot = vk[:, 0].reshape(R, C)
            theta = qk[:, 1].reshape(R, C)
            arm = self.length * np.cos(theta)
            f_tip = -self.c_tip * (x_dot + arm * vk[:, 1].reshape(R, C))
            f_cart = u[:, k] - self.c_cart * x_dot + f_tip
            qf[:, 0] = f_cart.reshape(-1)
            qf[:, 1] = (f_tip * arm).reshape(-1)
            qf[~np.isfinite(qf)] = 0.0
            for a, f in zip(arts, qf, strict=True):
                a.qf = f
            system.step()
            qk = np.array([a.qpos for a in arts], dtype=np.float64)
            vk = np.array([a.qvel for a in arts], dtype=np.float64)
            qs[k], vs[k] = qk, vk
        qs = qs.reshape(n, R, C, 2).transpose(1, 0, 2, 3)
        vs = vs.reshape(n, R, C, 2).transpose(1, 0, 2, 3)
        for i in range(C):
            for j in range(2):
                out[:, :, self.mj_q[i, j]] = qs[:, :, i, j]
                out[:, :, self.mj_v[i, j]] = vs[:, :, i, j]
        bad = ~(np.isfinite(qs).all(axis=(2, 3)) & np.isfinite(vs).all(axis=(2, 3)))  # (R, n)
        bad |= ~np.isfinite(u).all(axis=2)
        bad[~live] = True
        for r in np.flatnonzero(bad.any(axis=1)):
            if live[r]:
                self._failed += 1
            out[r, int(np.argmax(bad[r])) :, 1:] = np.nan

    def warnings(self) -> int:
        """Realisations whose state became non-finite (then NaN to the end of the chunk)."""
        return self._failed


ENGINE = RigidBodyEngine(
    name="physx",
    capabilities=Capabilities(
        precision="float32",
        device="cpu",
        rigid_body=True,
        linearize=False,
        deterministic=True,
        family="PhysX (SAPIEN)",
        trajectory_tolerance=TRAJECTORY_TOLERANCE,
        integrator="semi-implicit Euler (PhysX TGS articulation)",
        order=1.0,
        rod="rigid",
        twin=None,
    ),
    backend=lambda: PhysxRollout,
    requires=("sapien",),
    integrators=(),
    backend_workers=True,
    notes="PhysX 5 articulations through SAPIEN 3 (CPU, float32), explicit dampers",
)
