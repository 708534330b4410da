"""The registry of engines: the only place that knows engine names.

Entries are ``"module:attribute"`` strings imported on first use, so that an
engine whose package is missing (JAX, Drake, warp) costs nothing until it is
asked for and is then reported with the reason (:func:`availability`).
Third-party engines register through the ``cipval.engines`` entry-point group
(value ``"module:attribute"``), with no change to this file.
"""

from __future__ import annotations

import functools
import importlib
from importlib.metadata import entry_points

from .engine import Engine
from .params import ParameterError

#: name -> "module:attribute" of an object satisfying :class:`cipcore.engine.Engine`.
#: The first entry is the reference every other engine is validated against.
ENGINES: dict[str, str] = {
    "reduced": "reduced.engine:ENGINE",
    "mujoco": "cip.engines.rigid_body:MUJOCO",
    "mjx": "cip.engines.mjx:ENGINE",
    "drake": "cip.engines.drake:ENGINE",
    "mujoco-warp": "cip.engines.warp:ENGINE",
    "reduced-gpu": "reduced.gpu:ENGINE",
    "bullet": "cip.engines.bullet:ENGINE",
    "exudyn": "cip.engines.exudyn:ENGINE",
    "simbody": "cip.engines.simbody:ENGINE",
    "pinocchio": "cip.engines.pinocchio:ENGINE",
    "dart": "cip.engines.dart:ENGINE",
    "physx": "cip.engines.physx:ENGINE",
    "newton": "cip.engines.newton:ENGINE",
    "genesis": "cip.engines.genesis:ENGINE",
}

REFERENCE = "reduced"

_loaded: dict[str, Engine] = {}
_import_errors: dict[str, str] = {}


#: engines registered at run time (:func:`register_engine`), e.g. an ``--engine-cmd`` process
_runtime: dict[str, Engine] = {}


def register_engine(name: str, engine: Engine) -> None:
    """Register an engine object under ``name`` for this process (after the static entries)."""
    _runtime[name] = engine
    _loaded[name] = engine
    _import_errors.pop(name, None)


def registered_at_runtime(name: str) -> bool:
    """True for an engine registered in this process by :func:`register_engine` (another
    process does not know it: it runs in this one), False for one found by its entry."""
    return check_engine_name(name) in _runtime


@functools.cache
def _plugins() -> tuple[tuple[str, str], ...]:
    """The ``cipval.engines`` entry points, read once per process (a scan of every
    installed distribution's metadata: milliseconds, and engines are looked up often)."""
    return tuple((ep.name, ep.value) for ep in entry_points(group="cipval.engines"))


def _entries() -> dict[str, str]:
    entries = dict(ENGINES)
    for name, value in _plugins():
        entries.setdefault(name, value)
    for name in _runtime:
        entries.setdefault(name, f"<registered at run time: {name}>")
    return entries


def engine_names() -> tuple[str, ...]:
    """Every registered engine, installed or not, the reference first."""
    return tuple(_entries())


def _load(name: str) -> Engine | None:
    if name in _loaded:
        return _loaded[name]
    if name in _import_errors:
        return None
    module, _, attr = _entries()[name].partition(":")
    try:
        engine = getattr(importlib.import_module(module), attr)
    except ImportError as exc:  # the engine's module needs a package that is absent
        _import_errors[name] = f"cannot import {module}: {exc}"
        return None
    _loaded[name] = engine
    return engine


def check_engine_name(name: str) -> str:
    """``name`` if registered, else a one-line error listing the registered engines."""
    if name not in _entries():
        raise ParameterError(f"engine must be one of {', '.join(engine_names())}, got {name!r}")
    return name


def availability(name: str) -> str | None:
    """None when engine ``name`` can run here, else why not (one line)."""
    engine = _load(check_engine_name(name))
    if engine is None:
        return _import_errors[name]
    return engine.unavailable()


def get_engine(name: str) -> Engine:
    """The engine called ``name``; a one-line :class:`ParameterError` if unknown or unusable."""
    reason = availability(name)
    if reason is not None:
        raise ParameterError(f"engine {name!r} is not available here: {reason}")
    engine = _loaded[name]
    return engine


def engines_with(**capabilities: object) -> tuple[str, ...]:
    """Names of the available engines whose capabilities have the given values."""
    return tuple(n for n in declared_engines(**capabilities) if availability(n) is None)


def declared_engines(**capabilities: object) -> tuple[str, ...]:
    """Names of the engines whose capabilities have the given values, whether or not they
    can run here (an engine whose module cannot be imported declares nothing)."""
    out = []
    for name in engine_names():
        engine = _load(name)
        if engine is not None:
            caps = engine.capabilities
            if all(getattr(caps, k) == v for k, v in capabilities.items()):
                out.append(name)
    return tuple(out)
