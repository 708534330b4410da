"""The setting of one simulation, as values: what is simulated and how it is run.

A simulator of the balancing models (the reduced model, eqs. (3) and (5) of the
paper; the rigid-body CIP; the exact linear twins; the nonlinear stick, eq. (1))
takes one :class:`Scenario` (which model, at which gains, for how long, how many
noise realisations, which seed, from which initial balancing error) and, where
it needs them, a :class:`Recording` (what is kept of the trajectory) and an
:class:`Execution` (how the work is spread). The values are frozen: a scenario
is passed on from the command line to the kernels unchanged, and two equal
scenarios are the same simulation, bit for bit, whatever the execution.

The engines' interface (:class:`cipcore.engine.Engine`) keeps its flat keyword
options (``amplitude=``, ``decimate=``, ``threads=``, ...), the names its users and
external engines know; :func:`group_options` turns them into these values.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, fields
from typing import Any

import numpy as np

from .params import BalanceParams
from .schema import DEFAULT_MAX_BYTES


@dataclass(frozen=True)
class Scenario:
    """What is simulated.

    Attributes
    ----------
    model : "single" or "coupled" (:mod:`cipcore.models`).
    params : the paper's constants and the gains: alpha, beta (the feedback gain),
        gamma, nu (the noise amplitude), tau (the delay, s) and dt (the step, s).
    duration : simulated time in s, a whole number of steps.
    realizations : independent noise realisations.
    seed : root seed of the noise (:mod:`cipcore.seeds`).
    amplitude : initial balancing error in m: every realisation starts with the
        tip displaced by ``amplitude`` from the base, at rest, with that constant
        history over the delay.
    """

    model: str
    params: BalanceParams
    duration: float
    realizations: int = 1
    seed: int = 0
    amplitude: float = 0.01

    def with_params(self, params: BalanceParams) -> Scenario:
        """The same scenario at other parameters (e.g. another gain)."""
        return Scenario(self.model, params, self.duration, self.realizations, self.seed,
                        self.amplitude)  # fmt: skip


@dataclass(frozen=True)
class Recording:
    """What a simulation keeps of its trajectory.

    Attributes
    ----------
    decimate : keep every ``decimate``-th step.
    fields : the schema fields to keep (:data:`cipcore.schema.UNITS`); None keeps the
        simulator's default set.
    dtype : the recorded arrays' dtype (float32 halves the memory).
    max_bytes : a recording larger than this is refused before anything runs.
    """

    decimate: int = 1
    fields: tuple[str, ...] | None = None
    dtype: Any = np.float64
    max_bytes: int = DEFAULT_MAX_BYTES


@dataclass(frozen=True)
class Execution:
    """How a simulation's work is spread; never what it computes.

    Attributes
    ----------
    threads : worker threads (None: every core); the numbers do not depend on it.
    progress : show a progress bar on stderr.
    """

    threads: int | None = None
    progress: bool = False


#: the flat option names of each grouped value
GROUPS: dict[str, tuple[str, ...]] = {
    "recording": tuple(f.name for f in fields(Recording)),
    "execution": tuple(f.name for f in fields(Execution)),
}
_CLASSES: dict[str, Callable[..., Any]] = {"recording": Recording, "execution": Execution}


def group_options(options: Mapping[str, Any], accepted: Mapping[str, Any] | None = None
                  ) -> dict[str, Any]:  # fmt: skip
    """Flat keyword options as the grouped values the simulators take.

    ``{"decimate": 10, "threads": 2, "noise": n}`` becomes
    ``{"recording": Recording(decimate=10), "execution": Execution(threads=2),
    "noise": n}``; a group none of whose names is given is left out (the
    simulator's default); other names pass through. ``accepted`` (optional) maps
    the group names a simulator takes to anything: groups it does not take are not
    built, and their names pass through (so that the simulator refuses them).
    """
    out: dict[str, Any] = {}
    rest = dict(options)
    for group, names in GROUPS.items():
        if accepted is not None and group not in accepted:
            continue
        given = {k: rest.pop(k) for k in names if k in rest}
        if given:
            out[group] = _CLASSES[group](**given)
    out.update(rest)
    return out


def flat_options(fn: Callable[..., Any], scenario_options: tuple[str, ...] = ("amplitude",)
                 ) -> frozenset[str]:  # fmt: skip
    """The flat keyword names of an engine method whose work ``fn`` does.

    ``fn``'s own keyword-only parameters, each group replaced by the group's names,
    plus ``scenario_options`` (the :class:`Scenario` fields an engine method takes as
    keywords; pass ``()`` for a simulator that does not use them, e.g. lambda1).
    """
    import inspect

    names: set[str] = set(scenario_options)
    for p in inspect.signature(fn).parameters.values():
        if p.kind is not p.KEYWORD_ONLY:
            continue
        names.update(GROUPS.get(p.name, (p.name,)))
    return frozenset(names)


def engine_call(call: tuple[str, BalanceParams, float, int, int], options: Mapping[str, Any]
                ) -> tuple[Scenario, dict[str, Any]]:  # fmt: skip
    """The :class:`Scenario` and grouped keywords of an engine method's call.

    ``call`` is the method's ``(model, params, duration, n_realizations, seed)``
    and ``options`` its flat keywords (``amplitude=``, ``decimate=``, ...).
    """
    rest = dict(options)
    extra = {"amplitude": rest.pop("amplitude")} if "amplitude" in rest else {}
    model, params, duration, n, seed = call
    return Scenario(model, params, duration, n, seed, **extra), group_options(rest)


@dataclass(frozen=True)
class EngineTarget:
    """The rigid-body engine under validation and the model files it runs.

    Attributes
    ----------
    engine : the registered engine's name (:mod:`cipcore.registry`).
    integrator : MuJoCo's integrator name run instead of the file's (None: the file's).
    files : model name -> a user's MJCF run instead of the shipped
        ``models/cip_<model>.xml`` (None: the shipped files).
    """

    engine: str = "mujoco"
    integrator: str | None = None
    files: Mapping[str, str] | None = field(default=None, hash=False)

    def as_kwargs(self) -> dict[str, Any]:
        """``{"files": ..., "engine": ..., "integrator": ...}``: the keywords of the
        stages that take them one by one."""
        return {"files": self.files, "engine": self.engine, "integrator": self.integrator}
