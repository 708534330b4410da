"""PhysX through SAPIEN as a registered engine: the CIP as PhysX articulations, in float32.

SAPIEN 3.0 (``sapien``, PyPI; PhysX 5.3.1) drives a ``PhysxCpuSystem`` in a scene
without a renderer.  Every physical number is read from the compiled MuJoCo model
(:func:`cip.engines.drake_plant.geometry_from_mujoco`), and the model is built with
SAPIEN's component API (no URDF or MJCF parser); per controller i one fixed-base
reduced-coordinate articulation:

* rail: the fixed root link at the world origin;
* cart: a prismatic joint ``x_M<i>`` (PhysX slides along the joint frame's x: world
  +x) whose parent frame sits at the cart's reference position (x = +-l/2 in the
  coupled model), so that the joint coordinate is the MJCF ``qpos`` of the slide (m);
  the link carries the cart's mass M (kg; its rotational inertia, M kg m^2 about each
  axis, is never excited: the cart only translates);
* pendulum: a revolute joint ``theta_<i>`` at the cart's origin, its joint frame
  turned by +90 deg about z in both links so that PhysX's twist axis (the frame's x)
  is world +y: theta > 0 tilts the tip to +x, as in MuJoCo (a step from 0.1 rad turns
  the link by the quaternion (cos theta/2, 0, sin theta/2, 0)).  The MJCF's pole is
  massless; the link carries exactly the bob: mass m at the centre-of-mass pose
  (0, 0, L) of the link frame (``set_cmass_local_pose``, the MJCF's tip site) with the
  MJCF's central inertia I as its principal inertia (``set_inertia``, axes the link's),
  so that PhysX's articulated-body dynamics, which works with the link's spatial
  inertia about its centre of mass, sees I_yy + m L^2 about the hinge, MuJoCo's value
  (MuJoCo's 1e-12 kg m^2 point-mass regulariser is 5e-9 of m L^2, below float32's
  resolution of the sum);
* gravity: the MJCF's gravity vector (m/s^2), the scene's (``PhysxSceneConfig``, set
  for the system's creation only; SAPIEN's global default is restored after);
* nothing of PhysX's own acts besides: joint friction 0, armature 0, drives off
  (stiffness and damping 0), link linear and angular damping 0 (PhysX's default 0.05
  would damp), velocity limits at :data:`MAXVAL`, sleep threshold 0 (a copy at rest is
  never put to sleep), no collision shapes (nothing collides).

The step (one ``PhysxCpuSystem.step`` of dt, the model file's time step): the control
and the MJCF's dampers are generalised forces evaluated at the state at the start of
the step, explicit as in MuJoCo's ``Euler``
(:func:`cip.engines.drake_plant.generalized_forces`: on the cart u - c_cart v_M + F_t,
on the hinge F_t L cos(theta), F_t = -c_tip v_tip,x), set as the joints' forces
(``set_qf``, float32; PhysX keeps them until set again: they are set at every step).
PhysX's articulation step is semi-implicit Euler: the joint accelerations of the
articulated-body algorithm (gravity, joint forces, Coriolis at q, v), v+ = v + dt a,
then the constraint solver (the rod), then q+ = q + dt v+.  The solver is PGS
(:data:`SOLVER`), not SAPIEN's default TGS: TGS integrates the positions over its
position iterations as sub-steps, which adds float32 rounding (single model against
MuJoCo's Euler, below: 2.9e-6 with TGS at 10 position iterations, 8.4e-6 at 32,
6.1e-7 with PGS) and, with the rod, 1.2e-3 on the coupled model (TGS, 10 / 1
iterations).  On the single model PGS is MuJoCo's ``Euler`` step to float32: against
``mujoco.rollout`` (2 realisations x 1 s, 0.05 x the band-limited forces of
:func:`validation.checks.refinement.open_loop_forces`, seed 3, tilted 0.01 rad, |e| up
to 6.8e-3 m) the relative L2 distance of (qpos, qvel) is 6.1e-7; MuJoCo's own Euler
with its state rounded to float32 after every step is at 5.7e-7 from it: the floor
of a float32 state.  Coupled (both tilted): 1.8e-6 (MuJoCo's float32-rounded Euler:
5.1e-6; its soft rod against a rigid one: 5.5e-7, the Pinocchio engine's figure).

The rod (coupled model) is PhysX's distance joint (``PhysxDistanceJointComponent``)
between the two tips, the points (0, 0, L) of the pendulum links, of the second
balancer's articulation to the first's, with minimum = maximum distance = l (the
MJCF tendon's rest length), no spring (stiffness and damping 0) and tolerance 0
(SAPIEN's): PhysX then makes it one **bilateral** row on the tips' distance,
g = |p_1 - p_2| - l, a rigid constraint solved by PGS: the position iterations with a
bias on g (the positional correction), then the velocity iterations without it (the
velocity PhysX reports).  One velocity iteration does not solve that single row
(PhysX regularises rows on articulation links by the links' ``cfmScale``, 0.025 by
default and not exposed by SAPIEN 3.0: the probable cause): the coupled model's
distance to MuJoCo's Euler above is 1.5e-4 at one velocity iteration,
1.7e-5 at 2, 2.6e-6 at 3 and 1.7e-6 to 1.8e-6 from 4 on (position iterations 1 to
64 change it by less): :data:`SOLVER` runs 10 position (SAPIEN's default) and 8
velocity iterations.  The rod is exact to float32: PhysX computes g from the tips'
world positions, float32 numbers near x = +-0.5 m (resolution 6e-8 m): the tips'
distance (from the float32 joint coordinates, in float64) stays within 9e-8 m of l
over the 1 s above (joint angles to 0.015 rad), mean 8e-9 m, and that resolution is
the coupled model's error floor: an absolute rod noise of about 6e-8 m, which puts a
1e-6 m coupled trajectory 1.0e-2 to 1.3e-2 from the reduced model's
(:data:`TRAJECTORY_TOLERANCE`) and refinement's 1e-5 m ones at E0 6e-3 (below).

Validation: no exact twin of cipval's (``capabilities.twin`` None): cipval judges the
engine by time-step refinement (:mod:`validation.checks.refinement`: the open-loop
trajectories at dt = h .. h/8 must converge, order 1, to the exact zero-order-hold
solution of the linearised rigid body, the rod rigid), at the float32 setting
(``validation.checks.refinement.FLOAT32_SETTINGS``: single model |e| 1e-3 m, coupled
3e-3 m, 4 s; floors :data:`REFINEMENT_FLOOR_FLOAT32`).  The float64 setting (1e-5 m,
1 s, floor 1e-6) is out of float32's reach: measured there (sapien 3.0.3,
``refinement_check``, seeds 1-20) the single model's E0 is 3.1e-6 to 1.4e-5, the
interval's upper end up to 4.5e-5, order 1.000-1.002 (float32 rounding: MuJoCo's Euler
with its state rounded to float32 after every step shows the same floor), and the
coupled model's E0 4.2e-3 to 7.9e-3, order 0.55 to 0.74: the rod's float32 resolution,
an absolute noise (E0 falls as 1 / amplitude: 6.2e-4 median at 1e-4 m, 6.8e-5 at
1e-3 m with order 1.00), within which a 1e-3 tip-mass error was hidden.  At the float32
setting (``benchmarks/refinement_power.py --float32 --engines physx``, seeds 1-20):
single model E0 median 1.4e-5, upper end at most 8.2e-5, order 0.995-1.004; coupled E0
median 3.2e-5, upper end at most 1.1e-4, order 1.000-1.002: 0 false failures in 20
seeds on either; a 1e-3 tip-mass error (``make_fault("mass_ratio", 1e-3)``) gives E0
6.8e-4 to 1.4e-3 (single) and 5.2e-4 to 1.0e-3 (coupled), flagged at every seed, and
so is a 1e-4 error of the tip mass, the pendulum length or gravity on both models.

The state passed in at each chunk is set on the articulations (float32 joint
positions and velocities; time and the rest of the ``mjSTATE_FULLPHYSICS`` vector
pass through) unless a copy already holds it, the end of the previous chunk: setting
the joint positions makes PhysX recompute its link poses from them, which it
otherwise carries from step to step, and would move the next steps by float32
rounding (1.4e-7 of a velocity in a test); so a run split into chunks gives the same
numbers as one chunk, bit for bit.  The R realisations are R copies of the
articulations in one scene, all at the world origin (they have no shapes, so nothing
between them interacts; a copy placed far from the origin would lose float32
resolution): PhysX solves each copy as its own island, and a realisation's numbers
are the same, bit for bit, alone, in a batch of 5, in reverse order, beside a
realisation that failed, and split over 1, 2 or 3 worker processes.  A state beyond
:data:`MAXVAL` stops the realisation (NaN from that step; its copy is parked at rest).
The step is a Python loop of SAPIEN calls holding the GIL: the engine's ``threads``
are worker processes (:class:`cip.workers.ProcessBlocks`).  Measured (one process,
zero forces from 0.01 rad, 2 s, best of 3, on a 2-core machine at load 8-9 from other
jobs: rough figures):
single model 1.3e4 realisation-steps/s for one realisation, 4.3e4 for 8, 6.5e4 for 64
(the Pinocchio engine in the same run: 5.4e4, 3.2e4, 4.4e4); coupled 1.5e4, 1.7e4,
2.2e4 (Pinocchio 1.9e4, 2.2e4, 1.7e4).  PhysX's own step took 3 to 12 us of a
single-model realisation-step and 11 to 17 us of a coupled one (load 5), the rest is
the Python loop around it.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from typing import Any

import mujoco
import numpy as np

from cip.engines.drake_plant import CIPGeometry, generalized_forces
from cip.engines.rigid_body import RigidBodyEngine, semi_implicit_rigid
from cip.engines.rollout import ModelRollout
from cip.names import cart_body, cart_joint, hinge_joint, pendulum_body

#: Relative L2 distance of the balancing error to the reduced model allowed at 1e-6 m:
#: the rod's float32 resolution (module docstring) puts the coupled model at 1.0e-2 to
#: 1.3e-2 (seeds 7 and 11-13, 2 x 2 s and 8 x 10 s), the single at 5.6e-4 to 3.3e-3 (the
#: rigid body's cart reaction m/M, as the float64 engines); about twice the largest.
TRAJECTORY_TOLERANCE = 3e-2

#: The refinement floors (largest upper end of E0's interval) this float32 engine is held
#: to, per model: the float32 setting's
#: (``validation.checks.refinement.FLOAT32_SETTINGS``, where refinement_check takes them
#: from; module docstring): correct at most 8.2e-5 (single) and 1.1e-4 (coupled) over
#: seeds 1-20, a 1e-3 tip-mass error at least 1.2e-3 and 8.8e-4.
REFINEMENT_FLOOR_FLOAT32 = {"single": 1.2e-4, "coupled": 1.6e-4}

#: The largest magnitude of a state coordinate that the step accepts (MuJoCo's
#: ``mjMAXVAL``), and PhysX's velocity limits of links and joints (off in effect):
#: beyond it a realisation is stopped (NaN from that step) before float32 overflows.
MAXVAL = 1e10


@dataclass(frozen=True)
class Solver:
    """PhysX's constraint solver for the articulations (the rod's row).

    Attributes
    ----------
    tgs : True for TGS (SAPIEN's default), False for PGS.
    position_iterations : iterations with the positional bias (PGS), sub-steps (TGS).
    velocity_iterations : iterations without it.
    """

    tgs: bool
    position_iterations: int
    velocity_iterations: int

    def describe(self) -> str:
        """One line: the solver and its iteration counts."""
        kind = "TGS" if self.tgs else "PGS"
        return (
            f"PhysX {kind}, {self.position_iterations} position and "
            f"{self.velocity_iterations} velocity iterations"
        )


#: PGS, 10 position and 8 velocity iterations (module docstring)
SOLVER = Solver(tgs=False, position_iterations=10, velocity_iterations=8)


def _sapien() -> Any:
    with warnings.catch_warnings():
        # sapien looks for a system libvulkan for its renderer at import (none is used)
        warnings.simplefilter("ignore", UserWarning)
        import sapien
    return sapien


@dataclass
class PhysxCIP:
    """A PhysX scene holding R copies of the CIP.

    ``articulations[r][i]`` is balancer i of realisation r, its joint coordinates
    (x_i, theta_i) in that order; ``rods[r]`` realisation r's distance joint (coupled).
    """

    scene: Any
    system: Any
    articulations: list[list[Any]]
    rods: list[Any]
    geometry: CIPGeometry


def _balancer(sapien: Any, g: CIPGeometry, i: int) -> tuple[list[Any], Any, Any]:
    """Balancer i as a fixed-base articulation (module docstring), not yet in a scene.

    Returns (its three entities: rail, cart, pendulum; the root link; the pendulum link).
    """
    physx = sapien.physx
    M, m, L = g.cart_mass[i], g.bob_mass[i], g.pendulum_length[i]
    rail = physx.PhysxArticulationLinkComponent(None)
    cart = physx.PhysxArticulationLinkComponent(rail)
    pend = physx.PhysxArticulationLinkComponent(cart)
    for link, mass in ((rail, M), (cart, M)):  # the rail is fixed, the cart only translates
        link.set_mass(mass)
        link.set_inertia([mass, mass, mass])
    pend.set_mass(m)
    pend.set_inertia(list(g.bob_inertia[i]))
    pend.set_cmass_local_pose(sapien.Pose(p=[0.0, 0.0, L]))
    rail.joint.type = "fixed"
    cart.joint.type = "prismatic"
    cart.joint.pose_in_parent = sapien.Pose(p=[g.cart_x0[i], 0.0, 0.0])
    cart.joint.pose_in_child = sapien.Pose()
    turn = sapien.Pose(q=[np.sqrt(0.5), 0.0, 0.0, np.sqrt(0.5)])  # frame x to world +y
    pend.joint.type = "revolute"
    pend.joint.pose_in_parent = turn
    pend.joint.pose_in_child = turn
    for joint, name in ((cart.joint, cart_joint(i + 1)), (pend.joint, hinge_joint(i + 1))):
        joint.name = name
        joint.limit = np.array([[-np.inf, np.inf]], np.float32)  # free (PhysX: locked)
        joint.set_friction(0.0)
        joint.set_drive_properties(0.0, 0.0)
        joint.set_max_velocity(MAXVAL)
        joint.armature = np.zeros(1, np.float32)
    entities = []
    for link, name in ((rail, f"rail_{i + 1}"), (cart, cart_body(i + 1)),
                       (pend, pendulum_body(i + 1))):  # fmt: skip
        link.linear_damping = 0.0
        link.angular_damping = 0.0
        link.set_max_linear_velocity(MAXVAL)
        link.set_max_angular_velocity(MAXVAL)
        entity = sapien.Entity()
        entity.name = name
        entity.add_component(link)
        entities.append(entity)
    entities[0].pose = sapien.Pose()
    return entities, rail, pend


def build_scene(g: CIPGeometry, n_realizations: int, solver: Solver = SOLVER) -> PhysxCIP:
    """A PhysX CPU scene (time step ``g.timestep``, gravity ``g.gravity``) holding
    ``n_realizations`` copies of the CIP described by ``g`` (module docstring)."""
    sapien = _sapien()
    physx = sapien.physx
    default = physx.get_scene_config()  # a copy
    config = physx.get_scene_config()
    config.gravity = np.array(g.gravity, np.float32)
    config.enable_tgs = solver.tgs
    physx.set_scene_config(config)  # read when the system is created
    try:
        system = physx.PhysxCpuSystem()
    finally:
        physx.set_scene_config(default)
    system.timestep = g.timestep
    scene = sapien.Scene([system])  # no render system
    arts, rods = [], []
    for _ in range(n_realizations):
        row, pends, rod = [], [], None
        for i in range(g.n_controllers):
            entities, root, pend = _balancer(sapien, g, i)
            if i == 1 and g.rod_length is not None:
                # the rod: a distance joint on the second pendulum, to the first
                rod = physx.PhysxDistanceJointComponent(pend)
                entities[2].add_component(rod)
            for entity in entities:
                scene.add_entity(entity)
            art = root.articulation
            art.set_sleep_threshold(0.0)
            art.set_solver_position_iterations(solver.position_iterations)
            art.set_solver_velocity_iterations(solver.velocity_iterations)
            row.append(art)
            pends.append(pend)
        if rod is not None:
            rod.set_parent(pends[0])
            rod.pose_in_parent = sapien.Pose(p=[0.0, 0.0, g.pendulum_length[0]])
            rod.pose_in_child = sapien.Pose(p=[0.0, 0.0, g.pendulum_length[1]])
            rod.set_limit(g.rod_length, g.rod_length, 0.0, 0.0)  # bilateral, no spring
            rods.append(rod)
        arts.append(row)
    return PhysxCIP(scene=scene, system=system, articulations=arts, rods=rods, geometry=g)


class PhysxRollout(ModelRollout):
    """:class:`cip.runner.RolloutBackend` stepping the CIP with PhysX (module docstring).

    Parameters
    ----------
    model : the compiled MuJoCo CIP (:func:`cip.model.build`): the source of every
        physical parameter, the time step (``model.opt.timestep``) and the state layout.
    n_realizations : number of realisations (copies of the articulations in one scene;
        a call with more builds a larger scene).
    threads : ignored (the step is a Python loop holding the GIL): the engine's
        ``threads`` are worker processes (:class:`cip.workers.ProcessBlocks`).
    """

    #: the constraint solver (a subclass may set another, as the module docstring's TGS runs)
    solver = SOLVER

    @staticmethod
    def preload() -> None:
        """Import sapien (:class:`cip.workers.ProcessBlocks` forks after)."""
        _sapien()

    def __init__(self, model: mujoco.MjModel, n_realizations: int, threads: int) -> None:
        super().__init__(model)
        g = self.geometry
        self.cip = build_scene(g, n_realizations, self.solver)
        self.n_controllers = g.n_controllers
        self.columns = (self.mj_x, self.mj_theta, self.mj_xdot, self.mj_omega)
        #: the joint positions and velocities (R, C, 2) the copies hold (last chunk's end)
        self._held: tuple[np.ndarray, np.ndarray] | None = None

    def _ensure(self, n_realizations: int) -> list[Any]:
        """The first ``n_realizations`` copies' articulations, flat (r major): a larger
        scene is built when the present one holds fewer."""
        if n_realizations > len(self.cip.articulations):
            self.cip = build_scene(self.geometry, n_realizations, self.solver)
            self._held = None
        return [a for row in self.cip.articulations[:n_realizations] for a in row]

    def _load(self, q: np.ndarray, dq: np.ndarray, live: np.ndarray) -> None:
        """Set the joint positions ``q`` and velocities ``dq`` (R, C, 2, float32) of the
        first R copies, zero where not ``live``; a copy that holds them already is left
        as it is (its link poses too: module docstring)."""
        held = self._held
        zero = np.zeros(2, np.float32)
        for r in range(q.shape[0]):
            holds = held is not None and r < len(held[0]) and live[r]
            if holds and np.array_equal(held[0][r], q[r]) and np.array_equal(held[1][r], dq[r]):
                continue
            for i, art in enumerate(self.cip.articulations[r]):
                art.set_qpos(q[r, i] if live[r] else zero)
                art.set_qvel(dq[r, i] if live[r] else zero)

    def __call__(self, state: np.ndarray, ctrl: np.ndarray, out: np.ndarray) -> None:
        R, n = ctrl.shape[:2]
        C = self.n_controllers
        arts = self._ensure(R)
        cx, ct, cv, cw = self.columns
        u = self.begin(state, ctrl, out)  # (R, n, C) cart forces, N
        # the state as PhysX holds it: float32 joint positions (x, theta), velocities
        q = np.stack([state[:, cx], state[:, ct]], axis=-1).astype(np.float32)
        dq = np.stack([state[:, cv], state[:, cw]], axis=-1).astype(np.float32)
        live = (np.abs(state[:, 1:]) < MAXVAL).all(axis=1)  # False for NaN too
        self._load(q, dq, live)
        stop = np.where(live, n, 0)  # the step from which a realisation is NaN
        traj = np.empty((n, R, C, 4), np.float32)  # x, theta, v, omega after each step
        qf = np.empty((R, C, 2), np.float32)
        system = self.cip.system
        for k in range(n):
            # control and dampers at the state at the start of the step (module docstring)
            qf[..., 0], qf[..., 1] = generalized_forces(
                self.geometry, q[..., 1], dq[..., 0], dq[..., 1], u[:, k]
            )
            qf[~live] = 0.0
            for art, f in zip(arts, qf.reshape(-1, 2), strict=True):
                art.set_qf(f)
            system.step()
            q = np.array([art.get_qpos() for art in arts]).reshape(R, C, 2)
            dq = np.array([art.get_qvel() for art in arts]).reshape(R, C, 2)
            traj[k, ..., :2] = q
            traj[k, ..., 2:] = dq
            bad = live & ~(np.abs(traj[k]) < MAXVAL).all(axis=(1, 2))
            if bad.any():  # stopped: NaN from this step on, its copy parked at rest
                self._failed += int(bad.sum())
                live &= ~bad
                stop[bad] = k
                q[bad] = 0.0
                dq[bad] = 0.0
                zero = np.zeros(2, np.float32)
                for r in np.flatnonzero(bad):
                    for art in self.cip.articulations[r]:
                        art.set_qpos(zero)
                        art.set_qvel(zero)
        self._held = (q, dq)
        for j, cols in enumerate(self.columns):
            out[:, :, cols] = traj[..., j].transpose(1, 0, 2)
        for r in np.flatnonzero(stop < n):
            out[r, stop[r] :, 1:] = np.nan


ENGINE = RigidBodyEngine(
    name="physx",
    capabilities=semi_implicit_rigid(
        "PhysX",
        "PhysX articulation, PGS",
        TRAJECTORY_TOLERANCE,
        precision="float32",
        solver=SOLVER.describe(),
    ),
    backend=lambda: PhysxRollout,
    requires=("sapien",),
    integrators=(),
    backend_workers=True,  # threads are worker processes (the step holds the GIL)
    notes="PhysX 5 through SAPIEN 3 (CPU, float32): fixed-base articulations, explicit "
    "dampers, PGS; the rod a PhysX distance joint (rigid to float32's resolution)",
)
