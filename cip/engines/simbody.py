"""Simbody (through OpenSim) as a registered engine: the CIP as an OpenSim ``Model``.

Every physical number is read from the compiled MuJoCo model
(:func:`cip.engines.drake_plant.geometry_from_mujoco`), and the model is built with
OpenSim's API (no ``.osim`` file); per controller i:

* cart ``cart_<i>``: a body of mass M (kg) on a ``SliderJoint`` ``x_M<i>``
  along the world +x, its parent frame at the cart's reference position
  (x = -+l/2 in the coupled model), so that the coordinate is the MJCF
  ``qpos`` of the slide (m);
* pendulum ``pendulum_<i>``: a body of mass m with its centre of mass (the bob)
  at (0, 0, L) and the MJCF's central inertia, on a ``PinJoint`` ``theta_<i>``
  at the cart's origin whose joint frames are turned so that the pin's z axis
  is the world +y (theta > 0 tilts the tip to +x, as in MuJoCo);
* rod (coupled model): a ``ConstantDistanceConstraint`` of length l between
  the two tips (Simbody's holonomic distance constraint, enforced by
  projection of q and u after every step to :data:`CONSTRAINT_TOLERANCE`:
  **rigid**);
* gravity: the MJCF's gravity vector (m/s^2).

The control and the MJCF's damping (tip damping -gamma m v_tip,x on the
absolute tip velocity, cart damping -gamma M v_M) are generalised forces
(:func:`cip.engines.drake_plant.generalized_forces`), evaluated at the state at the
start of each step and held over it through the override actuation of one
``CoordinateActuator`` per coordinate: explicit, as in MuJoCo.

Time step: Simbody's Runge-Kutta-Merson integrator with a **fixed step**
dt (``Manager.setIntegratorFixedStepSize``: no error control, no
substeps), one ``Manager.integrate`` call per step; with the forces held,
the step is a 4th-order Runge-Kutta step of the gravity-inertia dynamics
followed by the constraint projection.  (Simbody's default, the
variable-step RK-Merson at an accuracy, would take any number of substeps
within one dt; it is not used.)  OpenSim's log is set to ``error`` so that
its per-integration messages do not reach stdout, and its log file sink is
removed (no ``opensim.log`` in the working directory).

The exact twin (:func:`twin_terms`, :mod:`reduced._twin_schemes`): the same
fixed Runge-Kutta-Merson step (Simbody's five stages, Hairer-Norsett-Wanner's
Table 4.1, the 4th-order solution propagated) on the linearised equations,
gravity at every stage, the control and the dampers held as the override
actuation holds them, the rod's force from J a = 0 at every stage (the stages
keep J q and J v, so the projection after the step changes nothing to first
order).  Measured (``python benchmarks/twin_floor.py --engines simbody
--duration 5 --realizations 2``, seed 1): relative L2 distance 3.7e-12 single
and 4.2e-12 coupled at 1e-6 m, growing as the amplitude squared above it
(3.7e-8 / 4.3e-8 at 1e-4 m), 4e-14 to 1e-13 below it; the rod's stretch is
1.5-4.9e-14 of the balancing error over 10 s.  A twin that re-evaluated the dampers at
every stage (as MuJoCo's RK4 does) is 3.9e-4 off: the twin sees which forces
are held.

One ``Manager`` (and integrator) per realisation on a shared ``Model``, so
that a realisation's numbers do not depend on the others of its batch; each
continues across chunks, and a state it did not produce (the first chunk) is
written into a fresh one.
"""

from __future__ import annotations

import math

import mujoco
import numpy as np

from cip.engines.drake_plant import CIPGeometry, generalized_forces
from cip.engines.rigid_body import RigidBodyEngine
from cip.engines.rollout import ModelRollout
from cip.mjcf_params import ModelMapping
from cipcore.engine import Capabilities

#: Relative L2 distance of the balancing error to the reduced model allowed at 1e-6 m
#: (``benchmarks/engine_floor.py``, seeds 0-3, 4 realisations, windows of 1-10 s): the
#: floor is at most 3.5e-3 (10 s; the rigid body's cart reaction m/M plus, for the
#: engines not stepping semi-implicit Euler, 6-7e-4 of time discretisation), every
#: control one step late gives at least 6.2e-3.  5e-3 separates the two.
TRAJECTORY_TOLERANCE = 5e-3

#: Tolerance of Simbody's constraint projection (relative; the rod's length error is below it).
CONSTRAINT_TOLERANCE = 1e-12


def _opensim():
    import opensim

    opensim.Logger.removeFileSink()  # else OpenSim writes opensim.log into the working directory
    opensim.Logger.setLevelString("error")
    return opensim


def twin_terms(mapping: ModelMapping) -> dict:
    """:class:`reduced.twin.TwinParams` keywords of Simbody's exact twin: the fixed-step
    Runge-Kutta-Merson step with the forces held and the rod rigid (J a = 0 at every stage)."""
    terms = {**mapping.twin_terms(), "integrator": "RK-Merson"}
    if terms.get("rod"):
        terms.update(rod_stiffness=0.0, rod_damping=0.0, rod_regulariser=0.0)
    return terms


class _Model:
    """The OpenSim model of the CIP and where its coordinates sit in Simbody's q and u."""

    def __init__(self, g: CIPGeometry) -> None:
        osim = _opensim()
        self.osim = osim
        model = osim.Model()
        model.setName("cip")
        model.setGravity(osim.Vec3(*g.gravity))
        ground = model.getGround()
        turn = osim.Vec3(-0.5 * math.pi, 0.0, 0.0)  # the pin's z axis onto the world +y
        pendula, coords = [], []
        self.actuators = []
        for i in range(g.n_controllers):
            M, m, L = g.cart_mass[i], g.bob_mass[i], g.pendulum_length[i]
            cart = osim.Body(f"cart_{i + 1}", M, osim.Vec3(0.0), osim.Inertia(M, M, M))
            pend = osim.Body(
                f"pendulum_{i + 1}", m, osim.Vec3(0.0, 0.0, L), osim.Inertia(*g.bob_inertia[i])
            )
            model.addBody(cart)
            model.addBody(pend)
            slide = osim.SliderJoint(
                f"x_M{i + 1}", ground, osim.Vec3(g.cart_x0[i], 0.0, 0.0), osim.Vec3(0.0),
                cart, osim.Vec3(0.0), osim.Vec3(0.0),
            )  # fmt: skip
            pin = osim.PinJoint(
                f"theta_{i + 1}", cart, osim.Vec3(0.0), turn, pend, osim.Vec3(0.0), turn
            )
            for joint in (slide, pin):
                model.addJoint(joint)
                coords.append(joint.getCoordinate())
            pendula.append(pend)
        for c in coords[0::2] + coords[1::2]:  # carts, then hinges
            act = osim.CoordinateActuator(c.getName())
            act.setName(f"force_{c.getName()}")
            act.setOptimalForce(1.0)
            act.setMinControl(-math.inf)
            act.setMaxControl(math.inf)
            model.addForce(act)
            self.actuators.append(act)
        if g.rod_length is not None:
            tip = [osim.Vec3(0.0, 0.0, g.pendulum_length[i]) for i in range(2)]
            model.addConstraint(
                osim.ConstantDistanceConstraint(
                    pendula[0], tip[0], pendula[1], tip[1], g.rod_length
                )
            )
        state = model.initSystem()
        for act in self.actuators:
            act.overrideActuation(state, True)
            act.setOverrideActuation(state, 0.0)
        self.model = model
        self.state0 = osim.State(state)
        # q index of each coordinate, carts then hinges (u has the same layout here)
        carts, hinges = coords[0::2], coords[1::2]
        probe = osim.State(state)
        for k, c in enumerate(carts + hinges):
            c.setValue(probe, float(k + 1), False)
        q = probe.getQ().to_numpy()
        self.q_index = np.array([int(np.flatnonzero(q == k + 1)[0]) for k in range(len(coords))])

    def manager(self, q: np.ndarray, u: np.ndarray, dt: float, time: float):
        """A fixed-step RK-Merson ``Manager`` started at q, u (Simbody's layout)."""
        osim = self.osim
        state = osim.State(self.state0)
        state.setTime(time)
        state.setQ(osim.Vector.createFromMat(q))
        state.setU(osim.Vector.createFromMat(u))
        mgr = osim.Manager(self.model)
        mgr.setIntegratorMethod(osim.Manager.IntegratorMethod_RungeKuttaMerson)
        mgr.setIntegratorFixedStepSize(dt)
        mgr.setIntegratorConstraintTolerance(CONSTRAINT_TOLERANCE)
        mgr.setWriteToStorage(False)
        mgr.setRecordStatesTrajectory(False)
        mgr.initialize(state)
        return mgr


class SimbodyRollout(ModelRollout):
    """:class:`cip.runner.RolloutBackend` stepping the CIP in Simbody (see the module docstring).

    Parameters
    ----------
    model : the compiled MuJoCo CIP (:func:`cip.model.build`).
    n_realizations : number of realisations (one ``Manager`` each).
    threads : ignored (the Python step loop holds the GIL): the engine's ``threads`` are worker
        processes (:class:`cip.workers.ProcessBlocks`), each building this class for a block.
    """

    @staticmethod
    def preload() -> None:
        """Import OpenSim (:class:`cip.workers.ProcessBlocks` forks after)."""
        _opensim()

    def __init__(self, model: mujoco.MjModel, n_realizations: int, threads: int) -> None:
        super().__init__(model)
        g = self.geometry
        self.osim_model = _Model(g)
        self.nc = g.n_controllers
        self.managers: list = [None] * n_realizations
        self.steps = [0] * n_realizations
        self.last: list[np.ndarray | None] = [None] * n_realizations

    def __call__(self, state: np.ndarray, ctrl: np.ndarray, out: np.ndarray) -> None:
        om, nc, dt = self.osim_model, self.nc, self.dt
        R, n = ctrl.shape[:2]
        u_ctrl = self.begin(state, ctrl, out)  # (R, n, C) cart forces, N
        qi = om.q_index
        setters = [a.setOverrideActuation for a in om.actuators]  # carts, then hinges
        for r in range(R):
            if not np.all(np.isfinite(state[r])):
                out[r, :, 1:] = np.nan
                continue
            if self.last[r] is None or not np.array_equal(self.last[r], state[r]):
                q, u = np.empty(2 * nc), np.empty(2 * nc)
                q[qi], u[qi] = state[r, self.mj_q], state[r, self.mj_v]
                self.managers[r] = om.manager(q, u, dt, 0.0)
                self.steps[r] = 0
            mgr = self.managers[r]
            x, v = state[r, self.mj_q].copy(), state[r, self.mj_v].copy()  # carts, then hinges
            qu = np.empty((n, 2, 2 * nc))  # Simbody's q and u after each step
            done = n
            for k in range(n):
                f_cart, t_hinge = generalized_forces(
                    self.geometry, x[nc:], v[:nc], v[nc:], u_ctrl[r, k]
                )
                s = mgr.getState()
                for set_force, f in zip(setters, f_cart.tolist() + t_hinge.tolist(), strict=True):
                    set_force(s, f)
                self.steps[r] += 1
                try:
                    s = mgr.integrate(self.steps[r] * dt)
                except RuntimeError:  # Simbody failed (e.g. the projection): diverged
                    done = k
                    self.managers[r] = None
                    break
                qu[k, 0], qu[k, 1] = s.getQ().to_numpy(), s.getU().to_numpy()
                x, v = qu[k, 0, qi], qu[k, 1, qi]
            out[r, :done][:, self.mj_q] = qu[:done, 0][:, qi]
            out[r, :done][:, self.mj_v] = qu[:done, 1][:, qi]
            if done < n:
                self.diverged(out, r, done)
            self.last[r] = out[r, -1].copy()


ENGINE = RigidBodyEngine(
    name="simbody",
    capabilities=Capabilities(
        family="Simbody",
        trajectory_tolerance=TRAJECTORY_TOLERANCE,
        integrator="RK-Merson (fixed step)",
        rod="rigid",
        twin="fixed-step Runge-Kutta-Merson with the control and dampers held, the rod rigid "
        "(its force from J a = 0 at every stage)",
    ),
    backend=lambda: SimbodyRollout,
    requires=("opensim",),
    integrators=(),
    twin_builder=twin_terms,
    # floor 3.7e-12 single, 4.2e-12 coupled at 1e-6 m (5 s); the smoke run's check (10 s,
    # seed 2011) 2.8e-11 / 1.9e-11: the suite's 1e-9 leaves a factor 35
    twin_tolerance=1e-9,
    # the twin's rod is rigid: the stretch over the balancing error at 1e-6 m, 10 s,
    # 2 realisations, measured 1.5e-14 to 4.9e-14 (seeds 1-4, 2011; 2.7e-15 over 1 s: it
    # drifts, far below the projection's 1e-12 m); 1e-12 leaves a factor 20
    rod_tolerance=1e-12,
    backend_workers=True,  # threads are worker processes (the step holds the GIL)
    notes="Simbody via OpenSim, fixed-step RK-Merson, rod as a ConstantDistanceConstraint",
)
