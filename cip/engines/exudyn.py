"""Exudyn as a registered engine: the CIP as point masses held by index-3 constraints.

Every physical number is read from the compiled MuJoCo model
(:func:`cip.engines.drake_plant.geometry_from_mujoco`).  The CIP lives in the
vertical (x, z) plane, Exudyn's 2D (x, y) plane with y up; per controller i:

* cart: a ``MassPoint2D`` of mass M (kg) at (x0_i + x_M, 0), its vertical
  coordinate fixed by a ``CoordinateConstraint`` to the ground (the slide);
* bob: a ``MassPoint2D`` of mass m at the tip, (x0_i + x_M + L sin theta,
  L cos theta); the massless pole of length L is an
  ``ObjectConnectorDistance`` between cart and bob, so theta > 0 tilts the tip
  to +x as in MuJoCo;
* the rod (coupled model): an ``ObjectConnectorDistance`` of length l
  (the MJCF tendon's rest length) between the two bobs.

The bob is a point: its central rotational inertia (1e-12 kg m^2 in the
MJCF, against m L^2 = 2e-4 kg m^2) is dropped; a bob of finite radius
(2/5 m r^2 above 1e-6 m L^2) is refused with a one-line error.  Gravity is
a load -m g on each bob's vertical coordinate.  The MJCF's damping (tip
damping -gamma m v_tip,x on the absolute tip velocity, cart damping
-gamma M v_M) and the control are evaluated at the state at the start of
each step and held over the step as ``LoadCoordinate`` values on the cart's
and the bob's x coordinates, explicit as in MuJoCo.

Time step: Exudyn's implicit second-order solver
(``MainSolverImplicitSecondOrder``), one step of dt per ``SolveSteps`` call,
constraints at index 3 (positions) solved by Newton to 1e-16 relative to the
step's initial residual (:data:`NEWTON_RELATIVE`): the rod and the poles are
**rigid**.  The residual holds the gravity loads (M g on the slide, about 1e5
times the control forces at 1e-6 m), so a looser test leaves the horizontal
dynamics that much less resolved: at 1e-12 the distance to the twin was
6.7e-7 (single, 1e-6 m, 1 s, seed 1), at 1e-16 it is 4e-12 and the steps take
about 25 % longer.  The scheme is Newmark with beta = 1/2,
gamma = 1 (:data:`NEWMARK_BETA`, :data:`NEWMARK_GAMMA`):

    v+ = v + dt a+,   q+ = q + dt (v + v+) / 2,   M a+ = f(q+) + F_n + G(q+)^T lambda+

so that a force F_n held over the step gives the impulse F_n dt exactly and
its effect starts at step n (a trapezoidal or generalized-alpha step would
spread it half over the next step, a measured half-step delay).  It is first
order and numerically dissipative (gamma > 1/2); with neither a_n in the
update, a chunk can resume from any (q, v) without a stored acceleration.

The exact twin (:func:`twin_terms`, :mod:`reduced._twin_schemes`): the same
Newmark step on the linearised equations, one linear solve per step, the rod a
Lagrange multiplier holding the tip separation's linear part at zero, the bob
a point mass (kappa = 0).  Measured (``python benchmarks/twin_floor.py
--engines exudyn --duration 5 --realizations 2``, seed 1): relative L2
distance 4.4e-12 single and 4.1e-12 coupled at 1e-6 m, growing as the
amplitude squared above it (3.7e-8 / 4.3e-8 at 1e-4 m: the angles'
second-order terms) and as Newton's absolute tolerance below it (1.9e-9
single at 1e-8 m).  The rod's stretch is the round-off of the displacement
coordinates, 3-5e-15 of the balancing error over 10 s.

One ``SystemContainer`` and solver per realisation, so that Newton's global
stopping test never couples realisations of one batch; the solver continues
across chunks, and a state it did not produce (the first chunk) is written
into it.
"""

from __future__ import annotations

import mujoco
import numpy as np

from cip.engines.drake_plant import CIPGeometry
from cip.engines.rigid_body import RigidBodyEngine
from cip.engines.rollout import ModelRollout
from cip.mjcf_params import ModelMapping
from cipcore.engine import Capabilities
from cipcore.params import ParameterError

#: Relative L2 distance of the balancing error to the reduced model allowed at 1e-6 m
#: (``benchmarks/engine_floor.py``, seeds 0-3, 4 realisations, windows of 1-10 s): the
#: floor is at most 3.5e-3 (10 s; the rigid body's cart reaction m/M plus, for the
#: engines not stepping semi-implicit Euler, 6-7e-4 of time discretisation), every
#: control one step late gives at least 6.2e-3.  5e-3 separates the two.
TRAJECTORY_TOLERANCE = 5e-3

#: Newmark parameters of the step (see the module docstring).
NEWMARK_BETA = 0.5
NEWMARK_GAMMA = 1.0
#: Newton tolerances of the implicit step (relative to the initial residual; absolute, N):
#: the relative one at 1e-16 resolves the control forces beside the gravity loads
#: (module docstring).
NEWTON_RELATIVE = 1e-16
NEWTON_ABSOLUTE = 1e-16
#: Largest bob central inertia (kg m^2), relative to m L^2, that a point mass may drop ...
POINT_MASS_INERTIA = 1e-6
#: ... beside the MJCF's own 1e-12 kg m^2 of a point-mass bob
#: (:func:`cip.model.bob_rotational_inertia`).
MJCF_POINT_INERTIA = 1e-12


def _settings(dt: float, n_steps: int):
    import exudyn as exu

    ss = exu.SimulationSettings()
    ti = ss.timeIntegration
    ti.numberOfSteps = n_steps
    ti.endTime = n_steps * dt
    ti.verboseMode = 0
    ga = ti.generalizedAlpha
    ga.useNewmark = True
    ga.newmarkBeta = NEWMARK_BETA
    ga.newmarkGamma = NEWMARK_GAMMA
    ti.newton.relativeTolerance = NEWTON_RELATIVE
    ti.newton.absoluteTolerance = NEWTON_ABSOLUTE
    ss.solution.file.write = False
    ss.linearSolver.solverType = exu.LinearSolverType.EXUdense
    return ss


def twin_terms(mapping: ModelMapping) -> dict:
    """:class:`reduced.twin.TwinParams` keywords of Exudyn's exact twin: the Newmark step
    (beta = 1/2, gamma = 1) with the rod rigid at position level (index 3), and the bob a
    point mass (kappa = 0, as this engine builds it)."""
    terms = {**mapping.twin_terms(), "integrator": "Newmark", "kappa": 0.0}
    if terms.get("rod"):
        terms.update(rod_stiffness=0.0, rod_damping=0.0, rod_regulariser=0.0)
    return terms


class _Realization:
    """One Exudyn system and solver of the CIP."""

    def __init__(self, g: CIPGeometry) -> None:
        import exudyn as exu
        from exudyn.itemInterface import (
            CoordinateConstraint,
            DistanceConstraint,
            LoadCoordinate,
            MarkerNodeCoordinate,
            MarkerNodePosition,
            MassPoint2D,
            NodePoint2D,
            NodePointGround,
        )

        self.exu = exu
        self.sc = exu.SystemContainer()
        mbs = self.sc.AddSystem()
        ground = mbs.AddNode(NodePointGround())
        m_ground = mbs.AddMarker(MarkerNodeCoordinate(nodeNumber=ground, coordinate=0))
        gy = g.gravity[2]  # m/s^2, MuJoCo's z is Exudyn's y
        self.cart_load, self.bob_load, bobs = [], [], []
        for i in range(g.n_controllers):
            x0, L = g.cart_x0[i], g.pendulum_length[i]
            cart = mbs.AddNode(NodePoint2D(referenceCoordinates=[x0, 0.0]))
            mbs.AddObject(MassPoint2D(mass=g.cart_mass[i], nodeNumber=cart))
            bob = mbs.AddNode(NodePoint2D(referenceCoordinates=[x0, L]))
            mbs.AddObject(MassPoint2D(mass=g.bob_mass[i], nodeNumber=bob))
            coord = [
                [mbs.AddMarker(MarkerNodeCoordinate(nodeNumber=n, coordinate=c)) for c in (0, 1)]
                for n in (cart, bob)
            ]
            mbs.AddObject(CoordinateConstraint(markerNumbers=[m_ground, coord[0][1]]))
            pos = [mbs.AddMarker(MarkerNodePosition(nodeNumber=n)) for n in (cart, bob)]
            mbs.AddObject(DistanceConstraint(markerNumbers=pos, distance=L))
            mbs.AddLoad(LoadCoordinate(markerNumber=coord[0][1], load=g.cart_mass[i] * gy))
            mbs.AddLoad(LoadCoordinate(markerNumber=coord[1][1], load=g.bob_mass[i] * gy))
            self.cart_load.append(mbs.AddLoad(LoadCoordinate(markerNumber=coord[0][0], load=0.0)))
            self.bob_load.append(mbs.AddLoad(LoadCoordinate(markerNumber=coord[1][0], load=0.0)))
            bobs.append(pos[1])
        if g.rod_length is not None:
            mbs.AddObject(DistanceConstraint(markerNumbers=bobs, distance=g.rod_length))
        mbs.Assemble()
        self.mbs = mbs
        self.dt = g.timestep
        self.solver = exu.MainSolverImplicitSecondOrder()
        self.steps = 0
        self.ss = _settings(self.dt, 2**30)  # numberOfSteps is a 32-bit int; 2^k keeps dt exact
        self.q = self.qd = np.zeros(0)

    def start(self, q: np.ndarray, v: np.ndarray) -> None:
        """(Re)start the solver at ODE2 displacements ``q`` and velocities ``v``."""
        sd, cfg = self.mbs.systemData, self.exu.ConfigurationType.Initial
        sd.SetODE2Coordinates(q, configuration=cfg)
        sd.SetODE2Coordinates_t(v, configuration=cfg)
        self.solver.InitializeSolver(self.mbs, self.ss)
        self.steps = 0
        self.q, self.qd = q, v

    def step(self, f_cart: np.ndarray, f_bob: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """One step of dt with the x forces (N) held on the carts and the bobs."""
        mbs = self.mbs
        for i, load in enumerate(self.cart_load):
            mbs.SetLoadParameter(load, "load", float(f_cart[i]))
            mbs.SetLoadParameter(self.bob_load[i], "load", float(f_bob[i]))
        self.steps += 1
        self.solver.it.endTime = self.steps * self.dt
        if not self.solver.SolveSteps(mbs, self.ss):
            raise RuntimeError("Exudyn's Newton iteration failed")
        sd = mbs.systemData
        self.q, self.qd = np.asarray(sd.GetODE2Coordinates()), np.asarray(sd.GetODE2Coordinates_t())
        return self.q, self.qd


class ExudynRollout(ModelRollout):
    """:class:`cip.runner.RolloutBackend` stepping the CIP in Exudyn (see the module docstring).

    Parameters
    ----------
    model : the compiled MuJoCo CIP (:func:`cip.model.build`).
    n_realizations : number of realisations (one Exudyn system each, created lazily).
    threads : ignored (the Python step loop holds the GIL): the engine's ``threads`` are worker
        processes (:class:`cip.workers.ProcessBlocks`), each building this class for a block.
    """

    @staticmethod
    def preload() -> None:
        """Import Exudyn (:class:`cip.workers.ProcessBlocks` forks after)."""
        import exudyn
        import exudyn.itemInterface  # noqa: F401

    def __init__(self, model: mujoco.MjModel, n_realizations: int, threads: int) -> None:
        super().__init__(model)
        g = self.geometry
        for i in range(g.n_controllers):
            dropped = max(g.bob_inertia[i]) - MJCF_POINT_INERTIA
            if dropped > POINT_MASS_INERTIA * g.bob_mass[i] * g.pendulum_length[i] ** 2:
                raise ParameterError(
                    "the exudyn engine models the bob as a point mass: bob_radius must be 0"
                )
        self.nc = g.n_controllers
        self.L = np.asarray(g.pendulum_length)
        self.x0 = np.asarray(g.cart_x0)
        self.c_tip = np.asarray(g.tip_damping)
        self.c_cart = np.asarray(g.cart_damping)
        self.systems: list[_Realization | None] = [None] * n_realizations
        self.last: list[np.ndarray | None] = [None] * n_realizations

    def to_exudyn(self, s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """ODE2 displacements and velocities (per controller: cart x, y, bob x, y) of ``s``."""
        x, th, v, om = s[self.mj_x], s[self.mj_theta], s[self.mj_xdot], s[self.mj_omega]
        L = self.L
        q = np.stack([x, 0 * x, x + L * np.sin(th), L * np.cos(th) - L], axis=1).ravel()
        qd = np.stack([v, 0 * v, v + L * np.cos(th) * om, -L * np.sin(th) * om], axis=1).ravel()
        return q, qd

    def from_exudyn(self, q: np.ndarray, qd: np.ndarray, s: np.ndarray) -> None:
        """Write Exudyn's ODE2 states ``q``, ``qd`` (..., 4 C) into the MuJoCo states ``s``
        (..., nstate), time untouched: one state, or a chunk's steps at once."""
        q, qd = q.reshape(*q.shape[:-1], self.nc, 4), qd.reshape(*qd.shape[:-1], self.nc, 4)
        dx, dy = q[..., 2] - q[..., 0], self.L + q[..., 3] - q[..., 1]
        dvx, dvy = qd[..., 2] - qd[..., 0], qd[..., 3] - qd[..., 1]
        s[..., self.mj_x] = q[..., 0]
        s[..., self.mj_xdot] = qd[..., 0]
        s[..., self.mj_theta] = np.arctan2(dx, dy)
        s[..., self.mj_omega] = (dy * dvx - dx * dvy) / (dx * dx + dy * dy)

    def __call__(self, state: np.ndarray, ctrl: np.ndarray, out: np.ndarray) -> None:
        R, n = ctrl.shape[:2]
        u = self.begin(state, ctrl, out)  # (R, n, C) cart forces, N
        for r in range(R):
            if not np.all(np.isfinite(state[r])):
                out[r, :, 1:] = np.nan
                continue
            if self.systems[r] is None:
                self.systems[r] = _Realization(self.geometry)
            sysr = self.systems[r]
            if self.last[r] is None or not np.array_equal(self.last[r], state[r]):
                sysr.start(*self.to_exudyn(state[r]))
            qd = sysr.qd
            odes = np.empty((n, 2, qd.size))  # Exudyn's q and qd after each step
            done = n
            for k in range(n):
                qd4 = qd.reshape(self.nc, 4)
                f_bob = -self.c_tip * qd4[:, 2]  # tip damping on the absolute tip x velocity
                f_cart = u[r, k] - self.c_cart * qd4[:, 0]
                try:
                    q, qd = sysr.step(f_cart, f_bob)
                except RuntimeError:  # a failed Exudyn step: the realisation diverged
                    done = k
                    self.systems[r] = None
                    break
                odes[k, 0], odes[k, 1] = q, qd
            self.from_exudyn(odes[:done, 0], odes[:done, 1], out[r, :done])
            if done < n:
                self.diverged(out, r, done)
            self.last[r] = out[r, -1].copy()


ENGINE = RigidBodyEngine(
    name="exudyn",
    capabilities=Capabilities(
        family="Exudyn",
        trajectory_tolerance=TRAJECTORY_TOLERANCE,
        integrator="Newmark(beta=1/2, gamma=1)",
        rod="rigid",
        twin="Newmark (beta 1/2, gamma 1) with the control and dampers held, gravity "
        "implicit, the rod a rigid index-3 constraint (Lagrange multiplier), the bob a point mass",
    ),
    backend=lambda: ExudynRollout,
    requires=("exudyn",),
    integrators=(),
    twin_builder=twin_terms,
    # floor 4.4e-12 single, 4.1e-12 coupled at 1e-6 m (5 s); the smoke run's check (10 s,
    # seed 2011) 2.9e-11 / 2.0e-11: the suite's 1e-9, the tolerance MuJoCo, Drake and the
    # faults' power are measured at, leaves a factor 35
    twin_tolerance=1e-9,
    # the twin's rod is rigid: the stretch over the balancing error at 1e-6 m, 10 s,
    # 2 realisations, measured 2.6e-15 to 5.3e-15 (seeds 1-4, 2011), the round-off of
    # displacements; 1e-12 leaves a factor 190
    rod_tolerance=1e-12,
    backend_workers=True,  # threads are worker processes (the step holds the GIL)
    notes="Exudyn point masses, index-3 distance constraints, implicit Newmark step",
)
