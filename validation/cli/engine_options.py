"""``--engine`` and ``--integrator`` of the commands that validate one rigid-body engine.

``run``, ``selftest`` and ``baseline`` validate the engine named by ``--engine``
(any rigid-body engine of :mod:`cipcore.registry`, MuJoCo by default) with the
same stages, checks and tolerances; ``--integrator`` steps the model file with
another of MuJoCo's integrators (Euler, implicit, implicitfast, RK4), for the
engines that follow the file's integrator, and the exact twin follows it.
"""

from __future__ import annotations

import argparse

from cipcore.params import ParameterError
from cipcore.registry import check_engine_name, engine_names
from validation.cli.args import add_engine_arg, add_integrator_arg
from validation.cli.domains import DOMAINS, INTEGRATORS, DomainError, add_option

__all__ = ["COMMAND_ENGINE", "INTEGRATORS", "add_engine_cmd_arg", "add_engine_options",
           "check_engine_options", "register_engine_cmd"]  # fmt: skip


#: The registry name of the engine given by ``--engine-cmd``.
COMMAND_ENGINE = "command"


def add_engine_cmd_arg(p: argparse.ArgumentParser) -> None:
    """Add ``--engine-cmd "CMD ARGS"`` (the chunk exchange protocol, :mod:`cip.engines.process`)
    and ``--engine-timeout SECONDS``."""
    add_option(
        p, "--engine-cmd", domain="command", metavar='"CMD ARGS"',
        help="an engine in another program, driven over stdin/stdout by the chunk exchange "
        f"protocol (README: Engines in other programs); registered as {COMMAND_ENGINE!r}",
    )  # fmt: skip
    add_option(
        p, "--engine-timeout", domain="timeout", metavar="SECONDS", default=None,
        help="--engine-cmd: seconds the engine has for its handshake and for each chunk, "
        "plus 1 ms per realisation-step of the chunk (default 60); past it the engine is "
        "killed and the command exits 4",
    )  # fmt: skip


def register_engine_cmd(command: str | None, timeout: float | None = None) -> str | None:
    """Register ``--engine-cmd``'s engine (``timeout``: ``--engine-timeout``); its registry
    name, or None without one."""
    if command is None:
        if timeout is not None:
            raise ParameterError("--engine-timeout applies to --engine-cmd only; give both")
        return None
    from cip.engines.process import process_engine
    from cipcore.registry import register_engine

    register_engine(COMMAND_ENGINE, process_engine(command, COMMAND_ENGINE, timeout))
    return COMMAND_ENGINE


def add_engine_options(p: argparse.ArgumentParser) -> None:
    """Add ``--engine``, ``--engine-cmd`` and ``--integrator`` to a command's parser."""
    add_engine_arg(
        p,
        default=None,
        help=f"the rigid-body engine to validate ({', '.join(engine_names())}; default mujoco)",
        metavar="NAME",
    )
    add_engine_cmd_arg(p)
    add_integrator_arg(
        p,
        f"step the model file with this MuJoCo integrator ({', '.join(INTEGRATORS)}; default: "
        "the file's <option integrator>); engines with their own stepper refuse it",
    )


def check_engine_options(a: argparse.Namespace) -> None:
    """Refuse, in one line, an unknown or unavailable engine or an integrator it cannot run.

    ``--engine-cmd`` registers the external engine and names it in ``a.engine``;
    without either option the engine is MuJoCo.
    """
    from validation.checks.agreement import rigid_engine

    command = getattr(a, "engine_cmd", None)
    if command is None and getattr(a, "engine_timeout", None) is not None:
        raise ParameterError("--engine-timeout applies to --engine-cmd only; give both")
    if command is not None:
        if a.engine is not None:
            raise ParameterError(
                "--engine and --engine-cmd both name the engine to validate; give one"
            )
        a.engine = register_engine_cmd(command, getattr(a, "engine_timeout", None))
    elif a.engine is None:
        a.engine = "mujoco"

    check_engine_name(a.engine)
    eng = rigid_engine(a.engine)  # availability and rigid body, one line each
    if a.integrator is None:
        return
    try:  # the parser canonicalised it; a caller from Python may pass any spelling
        a.integrator = DOMAINS["integrator"].check(a.integrator)
    except DomainError as exc:
        raise ParameterError(f"--integrator {exc}") from None
    if a.integrator not in eng.integrators:
        have = ", ".join(eng.integrators) or f"none: it steps with {eng.capabilities.integrator}"
        raise ParameterError(
            f"--integrator {a.integrator}: engine {a.engine!r} steps the file with ({have})"
        )
