"""What every rollout backend built from the compiled MuJoCo model shares.

An engine adapter (:mod:`cip.engines.bullet`, ``dart``, ``drake``, ``exudyn``,
``pinocchio``, ``simbody``, ...) is a :class:`cip.runner.RolloutBackend`: called with
the chunk's initial states (R, mjSTATE_FULLPHYSICS), the controls (R, n, nu) and an
output array (R, n, mjSTATE_FULLPHYSICS), it fills in the state after each of the n
steps.  :class:`ModelRollout` holds the part that does not depend on the engine: the
geometry read from the compiled model (:func:`cip.engines.drake_plant.geometry_from_mujoco`),
the time step, the motor forces, where the carts and hinges live in MuJoCo's state
vector, and the count of realisations that diverged (their samples NaN from the
failing step to the end of the chunk, which the drivers read as divergence).
"""

from __future__ import annotations

import importlib

import mujoco
import numpy as np

from cip.engines.drake_plant import CIPGeometry, geometry_from_mujoco


class ModelRollout:
    """The engine-independent half of a rollout backend (module docstring).

    A subclass is constructed as ``Backend(model, n_realizations, threads)``: ``model``
    the compiled MuJoCo CIP (:func:`cip.model.build`), the source of every physical
    parameter, of the time step (``model.opt.timestep``) and of the state layout;
    ``n_realizations`` the batch; ``threads`` the threads it may use (an engine whose
    step is a Python loop holding the GIL ignores it: its engine's ``threads`` are
    worker processes, :class:`cip.workers.ProcessBlocks`, which call :meth:`preload`
    before they fork).

    Attributes
    ----------
    geometry : every physical number of the model (lengths m, masses kg, dampers).
    dt : the model file's time step (s).
    motor, gear : the motor actuators' ids and gears: the cart force of controller i
        is ``ctrl[motor[i]] * gear[i]`` (N).
    mj_x, mj_theta, mj_xdot, mj_omega : indices of the cart positions (m), hinge angles
        (rad), cart velocities (m/s) and hinge rates (rad/s), one per controller, in
        the ``mjSTATE_FULLPHYSICS`` vector (time first, then qpos, then qvel).
    mj_q, mj_v : the cart positions then the hinge angles, and the cart velocities then
        the hinge rates: ``mj_x, mj_theta`` and ``mj_xdot, mj_omega`` in one index array.
    """

    #: the engine's Python modules, imported by :meth:`preload`
    modules: tuple[str, ...] = ()

    @classmethod
    def preload(cls) -> None:
        """Import the engine's modules (:class:`cip.workers.ProcessBlocks` forks after)."""
        for name in cls.modules:
            importlib.import_module(name)

    def __init__(self, model: mujoco.MjModel) -> None:
        g: CIPGeometry = geometry_from_mujoco(model)
        self.geometry = g
        self.dt = g.timestep
        self.motor = np.array(g.motor_id)
        self.gear = np.array(g.motor_gear)
        self.mj_x = 1 + np.array(g.qpos_x)
        self.mj_theta = 1 + np.array(g.qpos_theta)
        self.mj_xdot = 1 + model.nq + np.array(g.dof_x)
        self.mj_omega = 1 + model.nq + np.array(g.dof_theta)
        self.mj_q = np.r_[self.mj_x, self.mj_theta]
        self.mj_v = np.r_[self.mj_xdot, self.mj_omega]
        self._failed = 0

    def begin(self, state: np.ndarray, ctrl: np.ndarray, out: np.ndarray) -> np.ndarray:
        """Start a chunk: every sample of ``out`` holds the initial state with its time
        advanced by one step each (what a failing engine leaves); returns the cart
        forces (R, n, C) (N) of the controls ``ctrl`` (R, n, nu)."""
        n = ctrl.shape[1]
        out[...] = state[:, None, :]
        out[:, :, 0] = state[:, None, 0] + self.dt * np.arange(1, n + 1)
        return ctrl[:, :, self.motor] * self.gear

    def diverged(self, out: np.ndarray, r: int, k: int) -> None:
        """Realisation ``r`` failed at step ``k`` of the chunk: NaN from there on."""
        self._failed += 1
        out[r, k:, 1:] = np.nan

    def warnings(self) -> int:
        """Realisations that diverged (the engine failed, or its state or force stopped
        being a finite number): NaN from that step to the end of the chunk."""
        return self._failed
