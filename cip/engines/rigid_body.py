"""Rigid-body engines of the registry: the CIP stepped by a rollout backend.

Every rigid-body engine shares the model (the MJCF of :mod:`cip.model`), the
delayed random-gain control of :mod:`cip.runner` and the drivers
:func:`cip.simulate.simulate_full` and :func:`cip.lyapunov.lyapunov_full`;
what differs is the :class:`cip.runner.RolloutBackend` that advances the
states over a delay chunk.  :data:`MUJOCO` is MuJoCo on the CPU.
"""

from __future__ import annotations

import functools
import multiprocessing as mp
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from cip.linearize import linearize
from cip.lyapunov import lyapunov_full
from cip.mjcf_params import INTEGRATOR_NAMES, ModelMapping
from cip.model import CIPParams
from cip.runner import CIPRunner, MujocoRollout, RigidBody, RolloutBackend
from cip.simulate import simulate_full
from cip.workers import ProcessBlocks
from cipcore.driver import default_threads
from cipcore.engine import Capabilities, EngineMethods
from cipcore.models import BalanceModel, get_model
from cipcore.params import BalanceParams
from cipcore.results import LyapunovResult
from cipcore.scenario import Scenario, flat_options
from cipcore.schema import Trajectory

#: the flat options of the engine's methods that name the rigid body (cip.runner.RigidBody)
BODY_OPTIONS = ("physical", "backend", "mj_model")


def _with_body(options: dict[str, Any], name: str) -> dict[str, Any]:
    """Flat engine options with the rigid body's grouped into ``body=`` (named ``name``)."""
    body = {k: options.pop(k) for k in BODY_OPTIONS if k in options}
    return {**options, "body": RigidBody(name=name, **body)}


def _body_options(fn: Callable[..., Any], scenario_options: tuple[str, ...]) -> frozenset[str]:
    """The flat option names of an engine method whose work ``fn`` does."""
    return (flat_options(fn, scenario_options) - {"body"}) | set(BODY_OPTIONS)


#: realisation-steps below which a GIL-holding engine steps in this process: starting two
#: workers took 0.2-0.4 s (Drake, Bullet, Exudyn, Simbody at load 8), about 1e3-4e3 steps
#: of these engines, so below 1e4 steps the workers would cost more than they save
MIN_WORKER_STEPS = 10_000


def _in_worker(
    backend: type[RolloutBackend], model: Any, n_realizations: int, threads: int
) -> RolloutBackend:
    """``backend`` stepping a driver block in a worker process of its own
    (:class:`cip.workers.ProcessBlocks`), whatever thread count the runner passes."""
    return ProcessBlocks(backend, model, n_realizations, 1, one_in_process=False)


class RigidBodyChunks:
    """:class:`cipcore.engine.ChunkRunner` view of a :class:`CIPRunner`."""

    def __init__(self, runner: CIPRunner) -> None:
        self.runner = runner
        self.n_realizations = runner.n_realizations
        self.max_chunk = runner.d

    @property
    def step(self) -> int:
        return self.runner.step

    def advance(self, xi: np.ndarray) -> dict[str, np.ndarray]:
        before = self.runner.state
        states = self.runner.advance(xi)
        sel = np.concatenate([before[:, None], states[:, :-1]], axis=1)
        return self.runner.fields(sel)


def semi_implicit_rigid(
    family: str, stepper: str, trajectory_tolerance: float, **caps: Any
) -> Capabilities:
    """The capabilities of an engine that steps semi-implicit Euler (order 1) of its own
    (``stepper``: whose, e.g. ``"DART"``) with a rigid rod and no exact twin of cipval's:
    the refinement tier judges it (:mod:`validation.checks.refinement`).
    ``trajectory_tolerance``: relative L2 distance to the reduced model allowed at small
    amplitude; ``caps``: further :class:`cipcore.engine.Capabilities` fields (precision,
    kernels, solver)."""
    return Capabilities(family=family, trajectory_tolerance=trajectory_tolerance,
                        integrator=f"semi-implicit Euler ({stepper})", order=1.0, rod="rigid",
                        **caps)  # fmt: skip


@dataclass
class RigidBodyEngine(EngineMethods):
    """A rigid-body CIP engine: a name, its capabilities and its rollout backend.

    ``backend`` is a zero-argument callable returning the backend class (so that
    an engine whose package is absent can still be listed); ``requires`` names
    the modules it needs, checked by :meth:`unavailable`; ``probe`` (optional)
    returns a reason the engine cannot run here (e.g. no GPU); ``max_threads``
    caps the realisation blocks run concurrently (1 for engines that batch all
    realisations in one call); ``backend_workers`` says the backend's step holds the
    GIL (pydrake, pybullet, Exudyn, OpenSim): each of the drivers' ``threads``
    blocks of realisations is then stepped in a worker process of its own
    (:class:`cip.workers.ProcessBlocks`), the thread only computing the block's
    feedback and waiting on its process, instead of stepping on threads that the
    lock would serialise.  The blocks meet only at the end: one worker process for
    all of them, met at every delay chunk, ran at 1.51 to 1.55 times one process
    where the independent blocks ran at 1.73 to 1.75 and two processes that never
    exchange anything at 1.79 to 1.80 (Drake, coupled, 8 x 2 s, best of 5 rounds
    alternated, two series, 2 cores).

    What the validation needs to know about the discretisation: ``integrators``
    are the MuJoCo integrators the engine steps as the model file's ``<option
    integrator>`` says (empty: the engine has its own stepper,
    :attr:`cipcore.engine.Capabilities.integrator`, whatever the file says);
    ``twin_builder`` maps a model file's :class:`cip.mjcf_params.ModelMapping` to
    the keyword arguments of ``reduced.twin.TwinParams`` of the engine's exact
    twin (default :meth:`twin_terms`: the file's terms, soft rod, the file's
    integrator); ``twin_tolerance`` is the largest relative L2 distance of the
    balancing errors to that twin at 1e-6 m, set from the engine's measured floor
    (``benchmarks/twin_floor.py``; a dict gives one per model where the floors
    differ), and ``rod_tolerance`` the same for the rod's stretch (tip 1 - tip 2).
    """

    name: str
    capabilities: Capabilities
    backend: Any
    requires: tuple[str, ...] = ()
    probe: Any = None
    max_threads: int | None = None
    backend_workers: bool = False
    linearizer: Any = None
    notes: str = ""
    integrators: tuple[str, ...] = ("Euler",)
    twin_builder: Callable[[ModelMapping], dict[str, Any]] | None = None
    twin_tolerance: float | dict[str, float] = 1e-9
    rod_tolerance: float = 1e-3
    _why: str | None = field(default=None, init=False, repr=False)

    def unavailable(self) -> str | None:
        import importlib.util

        for mod in self.requires:
            if importlib.util.find_spec(mod) is None:
                return (
                    f"Python package {mod!r} is not installed (pip install 'cipval[{self.name}]')"
                )
        if self.probe is not None:
            return self.probe()
        return None

    def _backend(self) -> type[RolloutBackend]:
        return self.backend()

    def twin_tolerance_for(self, model: str) -> float:
        """The twin tolerance of ``model`` (one number, or one per model where floors differ)."""
        tol = self.twin_tolerance
        return float(tol[model]) if isinstance(tol, dict) else float(tol)

    def rollout(self) -> type[RolloutBackend]:
        """The engine's :class:`cip.runner.RolloutBackend` class (what a fault wraps)."""
        return self._backend()

    def twin_terms(self, mapping: ModelMapping) -> dict[str, Any]:
        """Keyword arguments of :class:`reduced.twin.TwinParams` for this engine's exact twin."""
        if self.twin_builder is not None:
            return self.twin_builder(mapping)
        integrator = mapping.integrator
        if not self.integrators:
            # its own stepper: the twin steps it where MuJoCo has it; an engine without an
            # exact twin (capabilities.twin None) is held to the semi-implicit Euler twin
            # at its declared twin_tolerance
            own = self.capabilities.integrator
            integrator = own if own in INTEGRATOR_NAMES.values() else "Euler"
        return {**mapping.twin_terms(), "integrator": integrator}

    def make_runner(self, model: BalanceModel, params: BalanceParams, n_realizations: int,
                    amplitude: float, physical: CIPParams | None) -> RigidBodyChunks:  # fmt: skip
        physical = physical or CIPParams.from_reduced(params)
        r = CIPRunner(model.name, params, physical, n_realizations, amplitude, threads=1,
                      backend=self._backend())  # fmt: skip
        return RigidBodyChunks(r)

    def accepted(self, method: str) -> frozenset[str]:
        if method == "simulate":
            return _body_options(simulate_full, ("amplitude",))
        return _body_options(lyapunov_full, ())

    def place(self, method: str, options: dict[str, Any], work: int) -> None:
        """Set the drivers' ``threads`` and ``backend`` options in place: capped at
        ``max_threads``; for a backend whose step holds the GIL, each of the
        ``threads`` driver blocks in a worker process of its own (the same numbers for
        any count), or one block in this process when the ``work``
        (realisation-steps) is below :data:`MIN_WORKER_STEPS` or this process is a
        pool's worker (a sweep point: daemonic, it may not start processes, and
        threads sharing the interpreter lock would gain nothing)."""
        if self.max_threads is not None:
            options["threads"] = min(options.get("threads") or self.max_threads, self.max_threads)
        backend = options.get("backend") or self._backend()
        if self.backend_workers:
            workers = options.get("threads") or default_threads()
            if work < MIN_WORKER_STEPS or mp.current_process().daemon:
                workers = 1
            if workers > 1:
                backend = functools.partial(_in_worker, backend)
            options["threads"] = workers
        options["backend"] = backend

    def simulate_scenario(self, scenario: Scenario, grouped: dict[str, Any]) -> Trajectory:
        tr = simulate_full(scenario, **_with_body(grouped, self.name))
        if not self.integrators:  # the engine's own stepper ran, whatever the file says
            tr.attrs["stepper"] = self.capabilities.integrator
        return tr

    def lyapunov_scenario(self, scenario: Scenario, grouped: dict[str, Any]) -> LyapunovResult:
        return lyapunov_full(scenario, **_with_body(grouped, self.name))

    def linearize(self, model: BalanceModel | str, physical: CIPParams | None = None):
        """The engine's linearisation about upright beside the reduced model's
        (:class:`cip.linearize.Linearization`), or None where it has none."""
        if self.linearizer is None:
            return None
        return self.linearizer(get_model(model).name, physical)


MUJOCO = RigidBodyEngine(
    name="mujoco",
    capabilities=Capabilities(
        linearize=True,
        family="MuJoCo",
        twin="the model file's terms, its soft rod (solref/solimp) and its integrator "
        "(Euler, implicit, implicitfast or RK4) as MuJoCo defines them",
    ),
    backend=lambda: MujocoRollout,
    integrators=("Euler", "implicit", "implicitfast", "RK4"),
    linearizer=linearize,
    notes="MuJoCo C engine, mujoco.rollout across threads",
)
