"""Drake as a registered engine: the CIP in a ``MultibodyPlant``, a second engine family.

The plant (:mod:`cip.engines.drake_plant`) is built from the same compiled MuJoCo
model as the ``mujoco`` engine, so both engines simulate the same
:class:`cip.model.CIPParams`; the delayed random-gain control of each delay
chunk is computed beforehand by :class:`cip.runner.CIPRunner` (it depends only
on states a delay old), so every engine sees the same controls for the same
seed.  :class:`DrakeRollout` maps ``mjSTATE_FULLPHYSICS`` vectors (time, qpos,
qvel) to one Drake ``Context`` per realisation and back, by the joint names
``x_M<i>``, ``theta_<i>``, and advances each realisation one discrete step at a
time with ``MultibodyPlant.ExecuteForcedEvents`` (one SAP step of dt), the
control and the explicit damping (:func:`cip.engines.drake_plant.generalized_forces`)
fixed on the applied-generalised-force input over the step.

Why one ``Context`` per realisation, not all realisations as model instances
of one plant: the batched plant ran about 4x faster per realisation-step
(about 25 us instead of about 115 us for the coupled CIP, Drake 1.51), but SAP's
stopping test and line search are global over the whole plant, so a
realisation's numbers then depend, at the 1e-13 level, on which others share
its batch; one plant per realisation keeps the same seed giving bit-identical
numbers for any batch split.

A SAP step that fails (Drake raises) is counted by :meth:`DrakeRollout.warnings`
and the realisation's remaining states are set to NaN, which the drivers treat
as divergence.

Measured (Drake 1.51.1, MuJoCo 4.0.0, paper parameters, beta = 20.306, 1e-6 m,
10 s, 4 realisations, seed 1; ``benchmarks/engine_distance_table.py``): the
relative L2 distance of the balancing errors to the reduced model is
2.967e-3 (single) and 2.892e-3 (coupled) at m/M = 1e-3 and 2.96e-5 / 2.89e-5
at m/M = 1e-5, as MuJoCo's: it is the cart reaction (m/M) alpha e common to
both rigid bodies.  Drake against MuJoCo: 1e-15 for the single model (the same
semi-implicit Euler with explicit forces) and 1.6e-7 for the coupled model,
whatever m/M: the two rod constraints differ in softness (MuJoCo's solref
time constant 2 ms against SAP's near-rigid regime; the tips of the coupled
model stay 4e-12 m from the rod length in Drake, 3e-10 m in MuJoCo, at 1e-3 m
amplitude).  At m/M = 1e-7 (``--mass-ratios 1e-7``) the coupled distance to the
reduced model is 6.89e-7 for Drake against 7.18e-7 for MuJoCo: the stiffer
rod is the closer one.  The declared ``trajectory_tolerance`` is MuJoCo's 1e-2: the
distance is the rigid body's m/M term, not the engine's precision.

The exact twin (:func:`twin_terms`): SAP's step with one bilateral constraint
row is linear, gamma = (v_hat - J v*) / (W + R), the same one-row solution as
MuJoCo's soft equality with k = 1 / (dt (dt + tau)), b = 1 / dt and R = W
beta^2 / (4 pi^2) (Castro et al. 2022, near-rigid regime; W = J M^-1 J^T).
Measured (Drake 1.51.1, coupled, 1e-6 m, 2 s, 2 realisations, seed 1): the
constants that reproduce Drake's rod are beta = 0.1 and tau = dt (distance to
the twin 2.5e-11, the rod's stretch matched to 1.4 %, the round-off of a
3.5e-15 m stretch computed from tip positions 1 m apart); MuJoCo's soft rod as
the twin instead gives 1.2e-7, and beta = 1 (``get_sap_near_rigid_threshold()``)
7.7e-8.  The single model (no rod) matches the Euler twin to 1.7e-12.

Throughput (``python benchmarks/bench_engines.py --engines mujoco,drake
--realizations 1,16,64 --threads 1``, coupled, 1000 steps, on a 2-core machine
shared with other jobs, load about 10): 1.2e3-1.6e3 realisation-steps/s
against MuJoCo's 3.1e4-7.1e4, a ratio of 0.02-0.04.  About 80 % of the time is
Drake's own discrete step (``ExecuteForcedEvents``: about 30 us for the single
and 115 us for the coupled model at load 2, the rod's SAP solve being most of
it), the rest the per-step Python calls.  No linearisation is offered: the
discrete SAP plant has no continuous-time qacc for a rigid rod.

Processes: pydrake's step holds the GIL, so the engine's ``threads`` are worker
processes (:class:`cip.workers.ProcessBlocks`), one per driver block of
consecutive realisations, each stepping its block in its own
:class:`DrakeRollout` while the block's thread computes its feedback; every
realisation has its own context and element-wise forces, so any split gives the
same numbers to the bit.  (Until this was wired through the engine, ``threads`` split the
realisations across threads, which the lock serialised: the earlier measurements
of 0.98x and 0.91x for two "processes" measured those threads.)  ``python
benchmarks/bench_engines.py --engines drake --realizations 8 --duration 2
--threads 1,2`` on an idle 2-core machine (load 0.2): 9.43e3 and 1.68e4
realisation-steps/s, 1.78 times.
"""

from __future__ import annotations

import mujoco
import numpy as np

from cip.engines.drake_plant import (
    build_plant,
    generalized_forces,
    load_pydrake,
)
from cip.engines.rigid_body import RigidBodyEngine
from cip.engines.rollout import ModelRollout
from cip.mjcf_params import ModelMapping
from cipcore.engine import Capabilities


class DrakeRollout(ModelRollout):
    """:class:`cip.runner.RolloutBackend` stepping the CIP in Drake's discrete ``MultibodyPlant``.

    One Drake ``Context`` per realisation, stepped one SAP step at a time.  The
    numbers of a realisation depend only on its own state and controls (one plant
    context each, the forces computed element-wise), so any split of the
    realisations into blocks gives bit-identical results.

    Parameters
    ----------
    model : the compiled MuJoCo CIP (:func:`cip.model.build`): the source of every
        physical parameter and of the state layout.
    n_realizations : number of realisations (one Drake ``Context`` each).
    threads : ignored.  ``ExecuteForcedEvents`` holds the GIL (two threads stepping
        two plants took as long as one thread stepping both), so the engine's
        ``threads`` are worker processes (:class:`cip.workers.ProcessBlocks`), each
        building this class for a consecutive block of realisations.
    """

    @staticmethod
    def preload() -> None:
        """Import pydrake's plant modules (:class:`cip.workers.ProcessBlocks` forks after)."""
        load_pydrake()

    def __init__(self, model: mujoco.MjModel, n_realizations: int, threads: int) -> None:
        super().__init__(model)
        g = self.geometry
        c = self.cip = build_plant(g)
        plant = self.plant = c.plant
        self.port = plant.get_applied_generalized_force_input_port()
        #: one context per realisation
        self.contexts = [plant.CreateDefaultContext() for _ in range(n_realizations)]
        nq = plant.num_positions()
        self.nx = nq + plant.num_velocities()
        self.theta, self.v_cart, self.omega = c.q_theta, nq + c.v_x, nq + c.v_theta
        self.mj_index = np.r_[self.mj_x, self.mj_theta, self.mj_xdot, self.mj_omega]
        self.drake_index = np.r_[c.q_x, c.q_theta, nq + c.v_x, nq + c.v_theta]

    def _advance(self, x: np.ndarray, u: np.ndarray) -> tuple[np.ndarray, int]:
        """States (R, n, nx) after each of n steps from Drake states ``x`` (R, nx) under
        cart forces ``u`` (R, n, C) (N); and the number of failed steps."""
        plant, port, cip = self.plant, self.port, self.cip
        R, n = u.shape[:2]
        x = x.copy()
        for r, ctx in enumerate(self.contexts[:R]):
            plant.SetPositionsAndVelocities(ctx, x[r])
        xs = np.empty((R, n, x.shape[1]))
        tau = np.zeros((R, plant.num_velocities()))
        alive = np.isfinite(x).all(axis=1)
        failed = 0
        for k in range(n):
            f_cart, t_hinge = generalized_forces(
                self.geometry, x[:, self.theta], x[:, self.v_cart], x[:, self.omega], u[:, k]
            )
            tau[:, cip.v_x] = f_cart
            tau[:, cip.v_theta] = t_hinge
            for r in np.flatnonzero(alive):
                ctx = self.contexts[r]
                port.FixValue(ctx, tau[r])
                try:
                    plant.ExecuteForcedEvents(ctx)
                except RuntimeError:  # SAP failed to converge: this realisation diverged
                    failed += 1
                    alive[r] = False
                    x[r] = np.nan
                    continue
                x[r] = plant.GetPositionsAndVelocities(ctx)
            xs[:, k] = x
        return xs, failed

    def __call__(self, state: np.ndarray, ctrl: np.ndarray, out: np.ndarray) -> None:
        x = np.zeros((ctrl.shape[0], self.nx))
        x[:, self.drake_index] = state[:, self.mj_index]
        u = self.begin(state, ctrl, out)  # (R, n, C) cart forces, N
        xs, failed = self._advance(x, u)
        self._failed += failed  # SAP failed to converge: those realisations are NaN in xs
        out[:, :, self.mj_index] = xs[:, :, self.drake_index]


#: SAP's near-rigid parameter beta of Drake's distance constraint (measured, module docstring).
NEAR_RIGID_BETA = 0.1


def twin_terms(mapping: ModelMapping) -> dict:
    """:class:`reduced.twin.TwinParams` keywords of Drake's exact twin: semi-implicit Euler
    (SAP with explicit forces) and the rigid rod in SAP's near-rigid regime (see above)."""
    terms = {**mapping.twin_terms(), "integrator": "Euler"}
    if terms.get("rod"):
        dt, mu, kappa = mapping.timestep, mapping.mass_ratio, mapping.kappa
        mobility = 2.0 * float(np.linalg.inv([[1.0 + mu, mu], [mu, mu * (1.0 + kappa)]]).sum())
        terms.update(
            rod_stiffness=1.0 / (2.0 * dt * dt),
            rod_damping=1.0 / dt,
            rod_regulariser=mobility * NEAR_RIGID_BETA**2 / (4.0 * np.pi**2),
        )
    return terms


ENGINE = RigidBodyEngine(
    name="drake",
    capabilities=Capabilities(
        family="Drake",
        integrator="SAP",
        rod="rigid",
        twin="semi-implicit Euler with explicit forces; the rigid rod as SAP's near-rigid "
        "one-row solution (beta 0.1, relaxation time dt)",
    ),
    backend=lambda: DrakeRollout,
    requires=("pydrake",),
    integrators=(),
    twin_builder=twin_terms,
    # the rod's stretch (~4e-15 m at 1e-6 m) is at the round-off of tip positions 1 m
    # apart: measured 1.4 % against the twin; 10 % leaves a factor 7 and still flags a
    # stretch off by one part in ten
    rod_tolerance=0.1,
    max_threads=None,
    backend_workers=True,  # "threads" are worker processes (pydrake's step holds the GIL)
    notes="Drake MultibodyPlant, discrete SAP, rod as a distance constraint",
)
