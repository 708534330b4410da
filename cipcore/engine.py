"""The engine interface: what every engine, and the reference model, provides.

An *engine* advances a batch of realisations of a balancing model
(:mod:`cipcore.models`) under the paper's delayed random-gain feedback

    F_i(t) = beta R_i(t) e_i(t - tau),   R_i = 1 + nu xi_i / sqrt(dt)      (eq. (5))

with the noise drawn from the shared per-realisation streams
(:mod:`cipcore.noise`), so that the same seed means the same draws in every
engine.  Because the control over the next tau depends only on states already
computed, an engine advances at most one delay chunk (d = tau/dt steps) at a
time under controls known in advance (:class:`ChunkRunner`).  Results come
back in the shared schema (:class:`cipcore.schema.Trajectory`,
:class:`cipcore.results.LyapunovResult`).

A new backend is one module with an object satisfying :class:`Engine` plus one
entry in :data:`cipcore.registry.ENGINES` (or a ``cipval.engines`` entry point).
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import asdict, dataclass
from typing import Any, Protocol, TypedDict, Unpack, runtime_checkable

import numpy as np

from .models import BalanceModel, get_model
from .params import BalanceParams, ParameterError
from .results import LyapunovResult
from .schema import Trajectory


@dataclass(frozen=True)
class Capabilities:
    """What an engine can do, declared by the engine itself.

    The defaults describe the common case, a deterministic float64 rigid body stepped
    on the CPU by compiled code, holding MuJoCo's soft rod with its ``Euler``; an
    engine declares what differs.

    Attributes
    ----------
    precision : "float64" or "float32": the floating-point type of its state.
    device : "cpu" or "gpu".
    rigid_body : True when it simulates the rigid-body CIP (angles, carts, a rod
        constraint, a small-angle regime), False for the reduced reference.
    linearize : True when it can return its linearisation about upright.
    deterministic : True when the same seed gives bit-identical numbers for any
        thread count and batch split.
    family : the engine family (e.g. "MuJoCo", "Drake", "reference").
    trajectory_tolerance : the relative trajectory distance to the reduced model
        at small amplitude that the engine's precision allows (the contract tests
        and ``cip-validate engines`` hold it to this).
    packs_points : True when a sweep should pack every grid point x realisation
        into one batch (:mod:`validation.sweeps.gpu`) instead of a point at a time.
    batch : True when every realisation of a call is one world of a batch stepped
        together, so that a call costs about as much for 16 realisations as for 3
        (warp's worlds: MuJoCo Warp, Newton; each step is a set of kernel launches
        whatever the worlds).  The multifidelity series then runs the engine's plain
        allocation in its one call and pairs all of it, and a fall back to plain
        sampling reruns nothing (:func:`validation.checks.agreement.multifidelity_series`).
    integrator : the time stepper, in MuJoCo's names ("Euler", "RK4",
        "implicit", "implicitfast") for MuJoCo-family engines, else a
        descriptive name ("SAP", "generalized-alpha", "semi-implicit Euler",
        "RK-Merson (variable step)").
    rod : how the rod between the tips is held: "soft" (MuJoCo's solref/solimp
        spring-damper), "rigid" (an exact holonomic distance constraint),
        "velocity-level" (a constraint on the velocities with Baumgarte position
        correction, Bullet's) or "penalty" (a spring of declared stiffness).
    twin : a short statement of how the engine's exact linear twin is built
        (:mod:`reduced.twin`), or None when no exact twin exists; such an engine
        is held to a declared, justified tolerance that the report states.
    solver : the constraint-solver setting the engine runs at where it is not the
        model file's (e.g. a fixed number of iterations); None: the file's, or the
        engine's own solver that ``rod`` and ``twin`` describe.
    kernels : what runs the steps: "native" (code compiled for the CPU: C, C++,
        numba or XLA) or "warp" (warp kernels, written for a CUDA device; without
        one they run only on warp's CPU device, by opt-in, and slowly).
    order : the order of accuracy of ``integrator`` as the engine runs it (the
        error at a fixed time falls as dt**order), where the engine declares it;
        None: the order cipval knows for ``integrator``
        (:data:`validation.checks.refinement.KNOWN_ORDERS`), else at least 0.8 is
        asked of the observed order.
    declared : False when the engine did not say how it steps (a version-1 chunk
        engine): it is held to the model file's exact twin where it matches it, and
        judged by time-step refinement where it does not.
    """

    precision: str = "float64"
    device: str = "cpu"
    rigid_body: bool = True
    linearize: bool = False
    deterministic: bool = True
    family: str = ""
    trajectory_tolerance: float = 1e-2
    packs_points: bool = False
    batch: bool = False
    integrator: str = "Euler"
    rod: str = "soft"
    twin: str | None = None
    solver: str | None = None
    kernels: str = "native"
    order: float | None = None
    declared: bool = True

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)


class SimulateOptions(TypedDict, total=False):
    """The keyword options of :meth:`Engine.simulate` (an engine refuses others).

    amplitude : initial balancing error (m).  decimate : record every n-th step.
    fields : schema fields to record.  noise : a :class:`cipcore.noise.GainNoise`
    or ``ArrayNoise`` instead of the seed's.  threads : worker threads.
    progress : show a progress bar.  Rigid-body engines only: physical : the
    rigid body's parameters (``cip.model.CIPParams``); mj_model : a compiled
    model file run instead of the generator's; backend : the rollout backend
    class (what a fault at the engine boundary wraps).  The reference only:
    stepper : "semi-implicit" or "explicit".
    """

    amplitude: float
    decimate: int
    fields: tuple[str, ...]
    dtype: Any
    noise: Any
    threads: int | None
    max_bytes: int
    progress: bool
    physical: Any
    mj_model: Any
    backend: Any
    stepper: str


class LyapunovOptions(TypedDict, total=False):
    """The keyword options of :meth:`Engine.lyapunov` (an engine refuses others):
    threads, progress, transient (s), epsilon (m); rigid-body engines also
    physical, mj_model and backend (as :class:`SimulateOptions`), and noise (a
    :class:`cipcore.noise.StackedNoise` of several seeds) with betas (a gain in 1/s^2
    per realisation): several gains in one batch."""

    noise: Any
    betas: Any
    threads: int | None
    progress: bool
    transient: float | None
    epsilon: float
    physical: Any
    mj_model: Any
    backend: Any
    stepper: str


def check_options(engine: str, method: str, options: Mapping[str, Any], accepted: Iterable[str]):
    """Refuse, in one line (:class:`cipcore.params.ParameterError`), an option that
    ``engine``'s ``method`` does not take: unknown to every engine, or one that does not
    apply to this one (e.g. a rigid body's ``physical`` given to the reduced model)."""
    accepted = frozenset(accepted)
    for key in options:
        if key in accepted:
            continue
        known = SimulateOptions.__optional_keys__ | LyapunovOptions.__optional_keys__
        why = "does not apply to it" if key in known else "is not an engine option"
        raise ParameterError(
            f"engine {engine!r} {method}: option {key!r} {why} "
            f"(it takes: {', '.join(sorted(accepted))})"
        )


@runtime_checkable
class ChunkRunner(Protocol):
    """A batch of realisations advanced at most ``max_chunk`` steps at a time.

    ``advance(xi)`` takes the standard-normal draws xi (R, n, C) of the next n
    steps and returns the shared schema's fields (R, n, C) sampled *before*
    each of those steps (sample j is the state at step ``step + j``), so that
    concatenating the chunks gives the :class:`Trajectory` of the run.
    """

    n_realizations: int
    max_chunk: int
    step: int

    def advance(self, xi: np.ndarray) -> dict[str, np.ndarray]: ...


@runtime_checkable
class Engine(Protocol):
    """An engine in the registry (see the module docstring)."""

    name: str
    capabilities: Capabilities

    def unavailable(self) -> str | None:
        """None when usable here, else the reason (missing package, no device)."""
        ...

    def runner(
        self,
        model: BalanceModel,
        params: BalanceParams,
        n_realizations: int,
        amplitude: float,
        *,
        physical: Any = None,
    ) -> ChunkRunner: ...

    def simulate(
        self,
        model: BalanceModel | str,
        params: BalanceParams,
        duration: float,
        n_realizations: int = 1,
        seed: int = 0,
        **options: Unpack[SimulateOptions],
    ) -> Trajectory: ...

    def lyapunov(
        self,
        model: BalanceModel | str,
        params: BalanceParams,
        duration: float,
        n_realizations: int = 8,
        seed: int = 0,
        **options: Unpack[LyapunovOptions],
    ) -> LyapunovResult: ...


def _engine_method(method: str, n_default: int, doc: str):
    """:meth:`Engine.simulate` or :meth:`Engine.lyapunov` for :class:`EngineMethods`: the two
    differ only in their name, their default number of realisations and what they run."""

    def call(
        self: EngineMethods,
        model: BalanceModel | str,
        params: BalanceParams,
        duration: float,
        n_realizations: int = n_default,
        seed: int = 0,
        **options: Any,
    ) -> Any:
        scenario, grouped = self._scenario(method, (model, params, duration), n_realizations,
                                           seed, options)  # fmt: skip
        if method == "simulate":
            return self.simulate_scenario(scenario, grouped)
        return self.lyapunov_scenario(scenario, grouped)

    call.__name__ = call.__qualname__ = method
    call.__doc__ = f"See :meth:`{doc}`."
    return call


class EngineMethods:
    """:meth:`Engine.simulate` and :meth:`Engine.lyapunov`, written once for every engine.

    The registry's interface keeps flat keywords (``amplitude=``, ``threads=``, ...:
    what users and the validation call); an engine class that inherits this names the
    options each method accepts (:meth:`accepted`), may adjust them before they are
    grouped (:meth:`place`), and runs the :class:`cipcore.scenario.Scenario` with the
    grouped values (:class:`cipcore.scenario.Recording`, ``Execution``, ...) that the
    call becomes (:meth:`simulate_scenario`, :meth:`lyapunov_scenario`).
    """

    name: str

    def accepted(self, method: str) -> Iterable[str]:
        """The flat keyword options ``method`` ("simulate" or "lyapunov") takes."""
        raise NotImplementedError

    def place(self, method: str, options: dict[str, Any], work: int) -> None:
        """Adjust ``options`` in place before they are grouped; ``work`` is the run's
        realisation-steps (realisations x steps, twice that for lyapunov's pairs).
        Default: nothing."""

    def simulate_scenario(self, scenario: Any, grouped: dict[str, Any]) -> Trajectory:
        """Run ``scenario`` with the grouped options: the trajectory."""
        raise NotImplementedError

    def lyapunov_scenario(self, scenario: Any, grouped: dict[str, Any]) -> LyapunovResult:
        """lambda1 (eq. (7)) of ``scenario`` with the grouped options."""
        raise NotImplementedError

    def make_runner(self, model: BalanceModel, params: BalanceParams, n_realizations: int,
                    amplitude: float, physical: Any) -> ChunkRunner:  # fmt: skip
        """The :class:`ChunkRunner` of :meth:`runner` for the resolved ``model``."""
        raise NotImplementedError

    def runner(
        self,
        model: BalanceModel | str,
        params: BalanceParams,
        n_realizations: int,
        amplitude: float,
        *,
        physical: Any = None,
    ) -> ChunkRunner:
        """See :meth:`Engine.runner`: ``n_realizations`` of ``model`` from the initial
        balancing error ``amplitude`` (m); ``physical``: the rigid body's parameters
        (default: those that map onto ``params``)."""
        return self.make_runner(get_model(model), params, n_realizations, amplitude, physical)

    simulate = _engine_method("simulate", 1, "Engine.simulate")
    lyapunov = _engine_method("lyapunov", 8, "Engine.lyapunov")

    def _scenario(self, method: str, run: tuple, n_realizations: int, seed: int,
                  options: dict[str, Any]) -> tuple[Any, dict[str, Any]]:  # fmt: skip
        from .scenario import engine_call  # (not at import: the CLI's start-up)

        model, params, duration = run
        check_options(self.name, method, options, self.accepted(method))
        n = getattr(options.get("noise"), "n_realizations", n_realizations)
        self.place(method, options, (2 if method == "lyapunov" else 1) * n
                   * round(duration / params.dt))  # fmt: skip
        return engine_call((get_model(model).name, params, duration, n_realizations, seed),
                           options)  # fmt: skip
