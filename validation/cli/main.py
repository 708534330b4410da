"""``cip-validate``: the command line of the suite.

Subcommands are thin: they parse, check every input, call the library, and
print.  One module per command group (:mod:`validation.cli.commands`), shared
argument helpers in :mod:`validation.cli.args`.  Exit status
(:mod:`validation.cli.exitcodes`): 0 when no check fails, 1 when a validation check
fails, 2 for a usage error (one line ``cip-validate: error: ...`` naming the
parameter and its allowed range), 3 when a regression number moved, 4 when
the engine crashed (partial results kept), 130 / 143 after SIGINT / SIGTERM
(finished work kept).  An output that cannot be
written (full disk, read-only file system, quota) is also exit 2, one line naming
the file; outputs are written atomically (:mod:`cipcore.atomic`), so nothing is
left under its name, and the line says where finished work was kept or what was lost.

Start-up is lazy: ``--help``, ``--version`` and an unknown command import no
command module (the top-level help lists :data:`COMMANDS`, name and one-line
help); ``cip-validate NAME ...`` imports only NAME's module and registers only
NAME's parser.  Command modules keep their heavy imports (scipy submodules,
engines, numba kernels) inside the functions that need them, so a command's
``--help`` and its argument errors stay fast as well.

Registering a command is one line in :data:`COMMANDS`::

    "name": ("validation.module", "one-line help"),

(``"validation.module:function"`` when the function is not called ``register``).
``register(sub)`` adds the command's function, described by the decorator
:func:`command`, with :func:`add_command` (or a command of subcommands with
:func:`add_group`), which gives ``sub.add_parser`` the table's help text (it may
register several commands; only the one asked for is kept): the top-level help
shows the table's text without importing the module, and the command's own parser
shows the same.
"""

from __future__ import annotations

import argparse
import importlib
import sys
from collections.abc import Callable, Sequence
from typing import Any

from cipcore import quickexit
from cipcore.atomic import WriteError
from validation.cli.args import (
    EXIT_FAIL,
    EXIT_OK,
    EXIT_SIGINT,
    EXIT_USAGE,
    PROG,
    CLIParser,
    forget_handled_keyboard_interrupt,
    ignore_signals_after_interrupt,
)
from validation.cli.exitcodes import EXIT_CRASH

__all__ = ["COMMANDS", "EXIT_FAIL", "EXIT_OK", "EXIT_USAGE", "add_command", "add_group",
           "build_parser", "command", "entry", "main"]  # fmt: skip

#: Every command, in the order of the top-level help: name -> ("module[:function]", help);
#: the function ``register`` unless named.
COMMANDS: dict[str, tuple[str, str]] = {
    "lyapunov": (
        "validation.cli.commands.analysis",
        "largest Lyapunov exponent lambda1 (mean, 95 %% CI)",
    ),
    "critical-gain": (
        "validation.cli.commands.analysis",
        "beta* where lambda1 equals a target (paper: 5e-4)",
    ),
    "stability": (
        "validation.cli.commands.analysis",
        "noise-free characteristic roots and stability region",
    ),
    "linearize": (
        "validation.cli.commands.simulation",
        "A, B of the MuJoCo CIP beside the reduced model's",
    ),
    "simulate": ("validation.cli.commands.simulation", "time series of any engine to a .npz file"),
    "run": (
        "validation.cli.commands.suite",
        "the validation suite: checks, paper table, figures, report",
    ),
    "baseline": ("validation.cli.commands.suite", "write a baseline results file for --baseline"),
    "sweep": (
        "validation.cli.commands.sweeping",
        "parameter study over a grid (resumable; local or Dask)",
    ),
    "sweep-plot": (
        "validation.cli.commands.sweeping",
        "a sweep metric against a parameter, with 95 %% bands",
    ),
    "sweep-export": (
        "validation.cli.commands.sweeping",
        "a sweep dataset as CSV (one row per point and realisation)",
    ),
    "render": (
        "validation.cli.commands.viewing",
        "a GIF or MP4 of a simulated run (offscreen MuJoCo)",
    ),
    "view": ("validation.cli.commands.viewing", "MuJoCo's interactive viewer on a simulated run"),
    "engines": (
        "validation.cli.commands.engines:add_engines_command",
        "validate every registered engine through the run's checks, one table",
    ),
    "contract": (
        "validation.cli.commands.contract",
        "the engine contract (reduced trajectory, delay, rod, energy, batch split)",
    ),
    "case": (
        "validation.cli.commands.case",
        "file protocol for engines that run the controller themselves",
    ),
    "experiment": ("validation.experiment.cli", "the paper's experiment: serve, analyze, bots"),
    "selftest": (
        "validation.faults.selftest:register_selftest",
        "inject each catalogued fault; show which check flags it",
    ),
}


Command = Callable[[argparse.Namespace], int]


def command(description: str) -> Callable[[Command], Command]:
    """Decorator of a command's function: the description its ``--help`` shows (argparse
    rewraps it), read by :func:`add_command`."""

    def describe(func: Command) -> Command:
        func.description = description  # type: ignore[attr-defined]
        return func

    return describe


def add_command(
    sub: Any, name: str, func: Command, help: str | None = None
) -> argparse.ArgumentParser:
    """Add command ``name`` to the subparsers ``sub``: its parser, run by ``func`` (described
    by :func:`command`).  ``help``: the one-line help of a subcommand; a command of
    :data:`COMMANDS` has the table's."""
    text = COMMANDS[name][1] if help is None else help
    p = sub.add_parser(name, help=text, description=func.description)  # type: ignore[attr-defined]
    p.set_defaults(func=func)
    return p


def add_group(sub: Any, name: str, description: str, dest: str, metavar: str) -> Any:
    """Add ``name``, a command of :data:`COMMANDS` made of subcommands: its parser and the
    required subcommand (parsed into ``dest``, shown as ``metavar``); returns the subparsers
    to :func:`add_command` them to."""
    p = sub.add_parser(name, help=COMMANDS[name][1], description=description)
    group = p.add_subparsers(dest=dest, metavar=metavar)
    group.required = True
    return group


def _version() -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("cipval")
    except PackageNotFoundError:
        return "unknown (not installed)"


class _OnlyOne:
    """The subparsers action as a register function sees it, keeping one command's parser.

    A module's register function adds all of its group's commands; the others go to a
    throw-away parser, so their names stay the table's stubs.
    """

    def __init__(self, sub: argparse._SubParsersAction, name: str) -> None:
        self._sub, self._name = sub, name

    def add_parser(self, name: str, **kwargs: Any) -> argparse.ArgumentParser:
        if name == self._name:
            return self._sub.add_parser(name, **kwargs)
        return CLIParser(prog=f"{PROG} {name}", add_help=False)

    def __getattr__(self, attr: str) -> Any:
        return getattr(self._sub, attr)


def register_function(name: str):
    """The register function of command ``name`` (imports its module)."""
    module, _, func = COMMANDS[name][0].partition(":")
    return getattr(importlib.import_module(module), func or "register")


def build_parser(command: str | None = None, *, full: bool = False) -> CLIParser:
    """The parser: ``command``'s own parser registered, every other command a stub.

    Parameters
    ----------
    command
        The command whose module is imported and whose parser is built in full; ``None``
        builds stubs only (top-level ``--help``, ``--version``, an unknown command).
    full
        Register every command in full (imports every command module; for tests).
    """
    parser = CLIParser(
        prog=PROG,
        description="Validate physics engines (MuJoCo and others in the registry) on a model "
        "of coupled inverted pendula against the reduced linear balancing model of Yoshida, "
        "Higeta & Watanabe (2011).",
    )
    parser.add_argument("--version", action="version", version=f"{PROG} {_version()}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    for name, (_target, help_text) in COMMANDS.items():
        if full or name == command:
            register_function(name)(_OnlyOne(sub, name))
        else:
            sub.add_parser(name, help=help_text, add_help=False)
    return parser


def domains_table() -> str:
    """The Markdown table of every option's declared domain (``docs/commands.md``).

    One row per command and option that has a domain (:mod:`validation.cli.domains`),
    commands in the order of :data:`COMMANDS`; builds every command's parser.
    """
    from validation.cli.domains import option_table

    rows, todo = [], [([], build_parser(full=True))]
    while todo:
        words, parser = todo.pop(0)
        for action in parser._actions:
            if isinstance(action, argparse._SubParsersAction):
                todo += [([*words, n], p) for n, p in action.choices.items()]
            elif words and not isinstance(action, argparse._HelpAction):
                name = "/".join(action.option_strings) or action.dest.upper()
                rows.append((" ".join(words), name, action))
    return option_table(rows)


def command_of(argv: Sequence[str]) -> str | None:
    """The command named in ``argv`` (its first word not starting with '-'), if known."""
    for word in argv:
        if not word.startswith("-"):
            return word if word in COMMANDS else None
    return None


def main(argv: Sequence[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    parser = build_parser(command_of(argv))
    try:
        args = parser.parse_args(argv)
    except SystemExit as exc:  # --help, --version, or a usage error already printed
        return exc.code if isinstance(exc.code, int) else EXIT_USAGE
    args.argv = argv  # a command that must run in a fresh process (render) re-runs these
    from cipcore.blas import one_blas_thread
    from cipcore.params import EngineError, ParameterError

    try:
        with one_blas_thread():  # every command's BLAS on one thread (cipcore.blas)
            return int(args.func(args) or 0)
    except ParameterError as exc:
        print(f"{PROG}: error: {' '.join(str(exc).split())}", file=sys.stderr)
        return EXIT_USAGE
    except EngineError as exc:  # an engine that broke outside a stage (e.g. its handshake)
        print(f"{PROG}: {' '.join(str(exc).split())}", file=sys.stderr)
        return EXIT_CRASH
    except KeyboardInterrupt:
        print(f"{PROG}: interrupted", file=sys.stderr)
        return EXIT_SIGINT
    except WriteError as exc:
        print(f"{PROG}: error: {' '.join(exc.message().split())}", file=sys.stderr)
        return EXIT_USAGE
    except OSError as exc:  # a directory or lock file that could not be made
        where = f"{exc.filename!r}: " if exc.filename else ""
        print(f"{PROG}: error: {where}{exc.strerror or exc}", file=sys.stderr)
        return EXIT_USAGE


def entry() -> None:
    """The console script ``cip-validate`` (and ``python -m validation.cli.main``).

    :func:`main` with its status as the process's; after a run stopped by SIGINT or
    SIGTERM both signals stay ignored until the process has exited
    (:func:`validation.cli.args.ignore_signals_after_interrupt`).  Once ``main``
    returned, the process ends without tearing its imported modules down
    (:mod:`cipcore.quickexit`: 0.35-0.4 s after a smoke run).
    """
    quickexit.arm()  # first: its atexit handler must run after every other one
    ignore_signals_after_interrupt()
    status = main()
    forget_handled_keyboard_interrupt()  # main returned: every KeyboardInterrupt was handled
    quickexit.exit(status)  # no module teardown once the outputs are written


if __name__ == "__main__":
    entry()
