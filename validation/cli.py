"""``cip-validate``: the command line of the suite.

Subcommands are thin: they parse, check every input, call the library, and
print.  One module per command group (:mod:`validation.commands`), shared
argument helpers in :mod:`validation.cli_args`.  Exit status
(:mod:`validation.exitcodes`): 0 when no check fails, 1 when a validation check
fails, 2 for a usage error (one line ``cip-validate: error: ...`` naming the
parameter and its allowed range), 3 when a regression number moved, 4 when
the engine crashed (partial results kept), 130 / 143 after SIGINT / SIGTERM
(finished work kept).
An output that cannot be
written (full disk, read-only file system, quota) is also exit 2, one line naming
the file; outputs are written atomically (:mod:`cipcore.atomic`), so nothing is
left under its name, and the line says where finished work was kept or what was lost.
"""

from __future__ import annotations

import sys
from collections.abc import Sequence

from cipcore.atomic import WriteError
from cipcore.params import ParameterError

from .cli_args import EXIT_FAIL, EXIT_OK, EXIT_SIGINT, EXIT_USAGE, PROG, CLIParser
from .cmd_engines import add_engines_command
from .commands import analysis, case, contract, simulation, suite, sweeping, viewing
from .experiment import cli as experiment_cli
from .selftest import register_selftest

__all__ = ["EXIT_FAIL", "EXIT_OK", "EXIT_USAGE", "build_parser", "main"]


def _version() -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("cipval")
    except PackageNotFoundError:
        return "unknown (not installed)"


def build_parser() -> CLIParser:
    parser = CLIParser(
        prog=PROG,
        description="Validate physics engines (MuJoCo and others in the registry) on a model "
        "of coupled inverted pendula against the reduced linear balancing model of Yoshida, "
        "Higeta & Watanabe (2011).",
    )
    parser.add_argument("--version", action="version", version=f"{PROG} {_version()}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    analysis.register(sub)
    simulation.register(sub)
    suite.register(sub)
    sweeping.register(sub)
    viewing.register(sub)
    add_engines_command(sub)
    contract.register(sub)
    case.register(sub)
    experiment_cli.register(sub)
    register_selftest(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    argv = list(sys.argv[1:] if argv is None else argv)
    try:
        args = parser.parse_args(argv)
    except SystemExit as exc:  # --help, --version, or a usage error already printed
        return exc.code if isinstance(exc.code, int) else EXIT_USAGE
    args.argv = argv  # a command that must run in a fresh process (render) re-runs these
    try:
        return int(args.func(args) or 0)
    except ParameterError as exc:
        print(f"{PROG}: error: {' '.join(str(exc).split())}", file=sys.stderr)
        return EXIT_USAGE
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


if __name__ == "__main__":
    sys.exit(main())
