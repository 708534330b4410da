"""Argument helpers shared by every ``cip-validate`` command.

One job: turn command-line text into checked values *before* any work starts.
Every bad value ends with exactly one line ``cip-validate: error: ...`` naming
the option and the allowed range, and exit status 2 (:class:`CLIParser`,
:func:`usage_error`); every option's help shows its default and unit
(:class:`HelpFormatter`).
"""

from __future__ import annotations

import argparse
import json
import os
import re
import signal
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any, NoReturn

from cipcore.models import MODEL_NAMES, get_model
from cipcore.params import PAPER, BalanceParams, ParameterError, whole_steps
from cipcore.registry import REFERENCE
from validation.cli.domains import add_option

EXIT_OK, EXIT_FAIL, EXIT_USAGE = 0, 1, 2
#: exit status after SIGINT / SIGTERM (128 + signal number, the shell's convention)
EXIT_SIGINT, EXIT_SIGTERM = 130, 143
PROG = "cip-validate"

#: Work (realisation-steps: realisations x duration / dt, summed over gains) above which
#: a command asks for ``--force``.  The paper profile's largest stage is ~6e8; at the
#: rigid-body engine's ~1e6 realisation-steps/s per core, 2e10 is several hours.
MAX_WORK = 2e10
#: Most delay steps tau / dt (the paper's: 100); every realisation holds a buffer of them.
MAX_DELAY_STEPS = 100_000


class HelpFormatter(argparse.ArgumentDefaultsHelpFormatter):
    """Help that shows every option's default (units are in each help text)."""

    def _get_help_string(self, action: argparse.Action) -> str:
        help_text = action.help or ""
        if action.default is None and "%(default)" not in help_text:
            return help_text  # "(default: None)" says nothing; the text says what happens
        if isinstance(action, argparse._StoreTrueAction):
            return help_text  # a flag: "(default: False)" says nothing either
        return super()._get_help_string(action) or help_text


#: a negative number is a value, not an option: -1, -1.5, -.5, -1e9, -2.5E-3, -inf, -nan
NEGATIVE_NUMBER = re.compile(r"^-(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?$|^-(inf|nan)$", re.IGNORECASE)


class CLIParser(argparse.ArgumentParser):
    """An ArgumentParser whose errors are one line ``cip-validate: error: ...``, exit 2.

    Also refuses an option given twice (the last would silently win) unless it is
    meant to repeat (``action="append"``), and reads negative numbers such as
    ``-1e9`` as values, not as options.
    """

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        kwargs.setdefault("formatter_class", HelpFormatter)
        super().__init__(*args, **kwargs)
        self._negative_number_matcher = NEGATIVE_NUMBER

    def parse_known_args(self, args: Any = None, namespace: Any = None) -> Any:
        if args is not None:
            self._refuse_repeats(list(args))
        return super().parse_known_args(args, namespace)

    def _refuse_repeats(self, args: list[str]) -> None:
        """A usage error when one of this parser's options occurs twice in ``args``."""
        commands: set[str] = set()
        for action in self._actions:
            if isinstance(action, argparse._SubParsersAction):
                commands.update(action.choices)
        repeatable = (argparse._AppendAction, argparse._CountAction, argparse._HelpAction,
                      argparse._VersionAction)  # fmt: skip
        seen: dict[str, str] = {}
        for i, token in enumerate(args):
            if token == "--" or token in commands:  # the rest belongs to a subcommand
                return
            option, eq, value = token.partition("=")
            action = self._option_string_actions.get(option)
            if action is not None and eq and value == "--" and action.nargs != 0:
                # argparse drops a "--" value and would store [] (Python 3.11)
                usage_error(f"{option} needs a value, got '--'")
            if action is None or isinstance(action, repeatable):
                continue
            if not eq and action.nargs != 0:
                value = " ".join(args[i + 1 : i + 1 + (action.nargs or 1)]
                                 if isinstance(action.nargs, int) or action.nargs is None
                                 else args[i + 1 : i + 2])  # fmt: skip
            if action.dest in seen:
                both = f" ({seen[action.dest]!r}, then {value!r})" if value else ""
                usage_error(f"{option} is given twice{both}; give it once")
            seen[action.dest] = value

    def error(self, message: str) -> NoReturn:
        # a declared domain's message reads "--tau must be ...", not "argument --tau: must be"
        usage_error(re.sub(r"^argument ([^:]+): (must |needs )", r"\1 \2", message))


def usage_error(message: str) -> NoReturn:
    """Print ``cip-validate: error: message`` (one line) and exit with status 2."""
    import sys

    text = " ".join(str(message).split())
    print(f"{PROG}: error: {text}", file=sys.stderr)
    raise SystemExit(EXIT_USAGE)


# ---------------------------------------------------------- option groups
def add_model_args(p: argparse.ArgumentParser, *, beta: bool = True) -> None:
    """--model and the reduced-model parameters (paper values as defaults)."""
    add_option(p, "--model", domain="model", default=MODEL_NAMES[0],
               help="balancing model: " + "; ".join(
                   f"{m} = {get_model(m).description}" for m in MODEL_NAMES))  # fmt: skip
    if beta:
        add_option(p, "--beta", domain="beta", required=True,
                   help="feedback gain beta (1/s^2), required")  # fmt: skip
    add_option(p, "--alpha", domain="alpha", default=PAPER["alpha"], help="g/L (1/s^2)")
    add_option(p, "--gamma", domain="gamma", default=PAPER["gamma"], help="damping gamma (1/s)")
    add_option(p, "--nu", domain="nu", default=PAPER["nu"], help="noise strength nu (s^1/2)")
    add_option(p, "--tau", domain="tau", default=PAPER["tau"], help="delay tau (s)")
    add_option(p, "--dt", domain="dt", default=PAPER["dt"], help="time step (s)")


def add_run_args(p: argparse.ArgumentParser, duration: float, realizations: int) -> None:
    """--duration, --realizations, --seed, --threads, --force."""
    add_option(p, "--duration", domain="duration", default=duration,
               help="simulated time per realisation (s)")  # fmt: skip
    add_option(p, "--realizations", domain="realizations", default=realizations,
               help="independent noise realisations (count)")  # fmt: skip
    add_seed_arg(p, 0, "root seed: fixes every random draw (integer >= 0)")
    add_threads_arg(p)
    add_force_arg(p)


def add_threads_arg(p: argparse.ArgumentParser, *, suite: bool = False) -> None:
    """--threads: the worker threads of one command; ``suite``: ``--workers`` (alias
    ``--threads``), the threads / processes of a validation run."""
    if suite:
        add_option(p, "--workers", "--threads", domain="workers", dest="workers", default=None,
                   help="threads / processes (count >= 1; default: all cores; --threads as in "
                   "`engines` and `simulate`); results do not depend on it")  # fmt: skip
        return
    add_option(p, "--threads", domain="workers", default=None,
               help="worker threads (count >= 1, at most 4 per core; default: all cores); "
               "results do not depend on it")  # fmt: skip


def add_force_arg(
    p: argparse.ArgumentParser, bound: float = MAX_WORK, unit: str = "realisation-steps"
) -> None:
    """--force: run past ``bound`` (:func:`check_work`'s, or :func:`refuse_work`'s)."""
    p.add_argument("--force", action="store_true",
                   help=f"run even when the estimated work exceeds {bound:.0e} {unit}")  # fmt: skip


def add_engine_arg(
    p: argparse.ArgumentParser,
    default: str | None = REFERENCE,
    help: str = "engine from the registry (an engine not installed here is refused with the "
    "reason)",
    metavar: str | None = None,
) -> None:
    """--engine NAME from :func:`cipcore.registry.engine_names` (any case); ``metavar`` None:
    the names themselves."""
    shown = {} if metavar is None else {"metavar": metavar}
    add_option(p, "--engine", domain="engine", default=default, help=help, **shown)


def add_integrator_arg(p: argparse.ArgumentParser, help: str) -> None:
    """--integrator NAME: one of MuJoCo's integrators (any case), None when not given."""
    add_option(p, "--integrator", domain="integrator", default=None, metavar="NAME", help=help)


def add_stepper_arg(p: argparse.ArgumentParser) -> None:
    """--stepper of the reduced reference (:func:`engine_options` refuses it elsewhere)."""
    add_option(p, "--stepper", domain="stepper", default=None,
               help="reduced engine's stepper: semi-implicit (like MuJoCo Euler) or "
               "explicit Euler-Maruyama (default: semi-implicit)")  # fmt: skip


def engine_options(a: argparse.Namespace, engine: Any) -> dict:
    """Engine keyword options from the command line (``--stepper``: the reference only)."""
    kw = {}
    if getattr(a, "stepper", None) is not None:
        if engine.capabilities.rigid_body:
            raise ParameterError(
                f"--stepper applies to the reduced reference only; {engine.name!r} is a "
                "rigid-body engine (its integrator is a physical setting)"
            )
        kw["stepper"] = a.stepper
    return kw


def add_simulation_args(p: argparse.ArgumentParser, duration: float, realizations: int) -> None:
    """The options of a command that runs one engine: :func:`add_model_args`,
    :func:`add_run_args`, --engine (the reference by default) and --stepper."""
    add_model_args(p)
    add_run_args(p, duration, realizations)
    add_engine_arg(p)
    add_stepper_arg(p)


def add_seed_arg(p: argparse.ArgumentParser, default: int | None, help: str) -> None:
    """--seed: the root seed of the command's noise draws (integer >= 0)."""
    add_option(p, "--seed", domain="seed", default=default, help=help)


def add_profile_arg(p: argparse.ArgumentParser, help: str) -> None:
    """--profile: the sizes of a validation run (:data:`validation.profiles.PROFILES`)."""
    add_option(p, "--profile", domain="profile", default="quick", help=help)


def add_mjcf_arg(p: argparse.ArgumentParser, help: str) -> None:
    """--mjcf PATH, repeatable: a user's CIP model file instead of a shipped one."""
    add_option(p, "--mjcf", domain="mjcf in", action="append", metavar="PATH", help=help)


def add_no_figures_arg(p: argparse.ArgumentParser, help: str) -> None:
    """--no-figures: the command's tables and reports without its figures."""
    p.add_argument("--no-figures", action="store_true", help=help)


def add_json_arg(p: argparse.ArgumentParser, help: str = "print one JSON object on stdout") -> None:
    """--json: the command's result as one JSON object on stdout."""
    p.add_argument("--json", action="store_true", help=help)


def params_from_args(
    a: argparse.Namespace, beta: float | None = None, beta_option: str = "--beta"
) -> BalanceParams:
    """The :class:`BalanceParams` of the parsed options (checked by BalanceParams).

    An error names the option as typed (``--tau``), or ``beta_option`` when ``beta`` is
    given (e.g. ``--beta-range``).
    """
    try:
        params = BalanceParams(
            beta=a.beta if beta is None else beta, alpha=a.alpha, gamma=a.gamma, nu=a.nu,
            tau=a.tau, dt=a.dt,
        )  # fmt: skip
    except ParameterError as exc:
        text = str(exc)
        name = text.split(" ", 1)[0]
        if name == "beta" and beta is not None:
            raise ParameterError(f"{beta_option}: {text}") from None
        if name in ("beta", "alpha", "gamma", "nu", "tau", "dt"):
            raise ParameterError(f"--{text}") from None
        raise
    if params.delay_steps > MAX_DELAY_STEPS:
        raise ParameterError(
            f"--tau / --dt: the delay is {params.delay_steps} steps (tau {params.tau:g} s / dt "
            f"{params.dt:g} s); at most {MAX_DELAY_STEPS} (the delay buffer holds them per "
            "realisation)"
        )
    return params


def dump(obj: Any) -> str:
    """One line of JSON (NaN and inf as null)."""
    from validation.report.document import jsonable

    return json.dumps(jsonable(obj))


# ------------------------------------------------------------ work checks
def check_work(
    option: str,
    realizations: int,
    duration: float,
    dt: float,
    *,
    runs: int = 1,
    fixed: float = 0.0,
    force: bool = False,
) -> float:
    """Estimated work in realisation-steps; a usage error above :data:`MAX_WORK` unless forced.

    The estimate is ``realizations x runs x duration / dt + fixed``: ``runs`` multiplies
    (e.g. gains of a critical-gain search, grid points of a sweep, the simulations of a
    selftest), ``fixed`` adds the realisation-steps that do not scale with ``option``
    (e.g. the selftest's refinement checks); the message names both.
    """
    whole_steps(option, duration, dt)  # before any work: the engines step whole dt
    work = float(realizations) * runs * duration / dt + fixed
    plus = f" + {fixed:.3g} fixed" if fixed else ""
    how = f"{realizations} realisations x {runs} run(s) x {duration:g} s / dt {dt:g} s{plus}"
    return refuse_work(option, work, how, force=force)


def refuse_work(
    option: str,
    work: float,
    how: str,
    *,
    bound: float = MAX_WORK,
    unit: str = "realisation-steps",
    force: bool = False,
) -> float:
    """``work`` (in ``unit``), or a one-line usage error naming ``option``, the estimate and
    ``how`` it was reckoned, when it exceeds ``bound`` and ``force`` is not given."""
    if work > bound and not force:
        raise ParameterError(
            f"{option}: estimated work {work:.3g} {unit} ({how}) exceeds {bound:.0e}; "
            "lower it or pass --force"
        )
    return work


# ------------------------------------------------------------ output paths
def _probe(directory: Path) -> str | None:
    """None when a file can be created in ``directory`` (tried, then removed), else why not."""
    import tempfile

    try:
        fd, name = tempfile.mkstemp(prefix=".cipval-probe-", dir=directory)
    except OSError as exc:
        return exc.strerror or str(exc)
    os.close(fd)
    os.unlink(name)
    return None


def check_out_file(option: str, path: str | Path, suffixes: tuple[str, ...] = ()) -> Path:
    """An output file: right extension, not a directory, in a directory we can write.

    Checked by creating (and removing) a probe file there, so it holds for root too.
    """
    p = Path(path)
    if suffixes and p.suffix.lower() not in suffixes:
        raise ParameterError(
            f"{option} must name a {' or '.join(suffixes)} file, got {str(path)!r}"
        )
    if p.is_dir():
        raise ParameterError(f"{option}: {str(path)!r} is a directory, expected a file")
    parent = p.parent
    if not parent.is_dir():
        why = "is not a directory" if parent.exists() else "does not exist"
        raise ParameterError(f"{option}: cannot write {str(path)!r}: {str(parent)!r} {why}")
    why = _probe(parent)
    if why is not None:
        raise ParameterError(f"{option}: cannot write in {str(parent)!r} ({why})")
    if p.exists() and not os.access(p, os.W_OK):
        raise ParameterError(f"{option}: cannot write {str(path)!r}: file is not writable")
    return p


def check_out_dir(option: str, path: str | Path) -> Path:
    """An output directory we can write in: created here (with parents) if absent."""
    p = Path(path)
    if p.exists() and not p.is_dir():
        raise ParameterError(f"{option}: {str(path)!r} exists and is not a directory")
    try:
        p.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ParameterError(
            f"{option}: cannot create directory {str(path)!r} ({exc.strerror or exc})"
        ) from None
    why = _probe(p)
    if why is not None:
        raise ParameterError(f"{option}: cannot write in directory {str(path)!r} ({why})")
    return p


# ---------------------------------------------------------------- signals
#: Whether signals stay ignored after a run stopped by one (see :func:`interrupt_signals`);
#: set only by the console script, :func:`validation.cli.main.entry`.
_AFTER_SIGNAL = {"ignore": False}


def ignore_signals_after_interrupt() -> None:
    """Make :func:`interrupt_signals` leave SIGINT and SIGTERM ignored, and blocked
    (``pthread_sigmask``), after a signal.

    For the console script alone, whose process is on its way out once a signal
    stopped it: Python resets a handler of its own to the default action when the
    interpreter finalises, and a SIGINT arriving then (a second Ctrl-C, a signal to
    the process group) would kill the exiting process by it, with status -SIGINT
    instead of the first signal's (seen once in CI: a run stopped by SIGTERM that
    printed its message and then ended killed by SIGINT).  Ignoring alone is not
    enough where finalisation sets the default action back before the process ends,
    so both signals are blocked too: a later one stays pending through the exit.  (A
    resumed run that printed "interrupted by SIGTERM" and ended with -2, 1 run in 6 on
    a loaded machine, and with 130 after the block, had another cause: CPython's own
    exit by SIGINT, see :func:`forget_handled_keyboard_interrupt`.)  A program that calls
    :func:`validation.cli.main.main` itself keeps its own handlers.
    """
    _AFTER_SIGNAL["ignore"] = True


def forget_handled_keyboard_interrupt() -> None:
    """Clear CPython's record of an unhandled KeyboardInterrupt once ours was handled.

    CPython ends a process whose KeyboardInterrupt went unhandled by SIGINT (status
    -2, or 130 where SIGINT is blocked; bpo-1054041), and decides so from a flag that
    every code object run through ``PyRun_String`` sets when a KeyboardInterrupt leaves
    it, and that nothing clears when the exception is then caught further up.  Extension
    modules run such code (MuJoCo's ``_callbacks``, pydrake, Exudyn, Boost.Python): in a
    smoke run the one call is ``mujoco.set_mju_user_warning`` when :mod:`cip.model` is
    imported, at the start of the first engine stage, so a signal that arrived just then
    left a run that stopped cleanly and returned 143 ending with 130 under
    ``python -m`` (seen in CI: "interrupted by SIGTERM" printed, status 130; the console
    script's file exits before that check).  Running one
    trivial statement through ``PyRun_String`` clears the flag: CPython resets it
    before each such run (``run_eval_code_obj``).  Called by the console script after
    :func:`validation.cli.main.main` returned, i.e. with no KeyboardInterrupt in flight.
    """
    try:
        import ctypes

        # a prototype of our own: the shared ctypes.pythonapi.PyRun_String keeps its types
        proto = ctypes.PYFUNCTYPE(ctypes.py_object, ctypes.c_char_p, ctypes.c_int,
                                  ctypes.py_object, ctypes.py_object)  # fmt: skip
        run = proto(("PyRun_String", ctypes.pythonapi))
    except (ImportError, AttributeError, OSError):  # no ctypes, or not CPython: no such flag
        return
    py_eval_input = 258
    run(b"None", py_eval_input, {}, {})


def _first_arrival(fd: int, fallback: int) -> int:
    """The signal that arrived first, from the bytes the C-level handler wrote to ``fd``.

    Python runs the handlers of signals pending together in the order of their
    numbers (SIGINT, 2, before SIGTERM, 15), not in the order they came, e.g. when
    both arrive during one long call into C; the wakeup file descriptor
    (:func:`signal.set_wakeup_fd`) receives each signal's number as it arrives.
    """
    try:
        data = os.read(fd, 4096)
    except (BlockingIOError, OSError):
        data = b""
    order = [b for b in data if b in (signal.SIGINT, signal.SIGTERM)]
    return int(order[0]) if order else fallback


@contextmanager
def interrupt_signals() -> Iterator[dict]:
    """Turn SIGINT and SIGTERM into KeyboardInterrupt; the dict names the signal received.

    Installed explicitly, so that it works even where a parent process started
    us with SIGINT ignored.

    The first signal to arrive decides: it raises KeyboardInterrupt and names the
    exit status (:func:`interrupted_status`), even where a second one is pending
    beside it (:func:`_first_arrival`); a later one is counted in ``got["later"]``
    and raises nothing, so that it cannot break off the saving of the finished work.
    On leaving the block the old handlers and wakeup descriptor return, except in the
    console script after a signal, where both signals stay ignored through the
    interpreter's exit (:func:`ignore_signals_after_interrupt`).
    """
    got: dict[str, int | None] = {"signal": None, "later": 0}
    read_fd, write_fd = os.pipe()
    os.set_blocking(read_fd, False)
    os.set_blocking(write_fd, False)

    def handler(signum: int, frame: object) -> None:
        if got["signal"] is not None:
            got["later"] = int(got["later"] or 0) + 1
            return
        got["signal"] = _first_arrival(read_fd, signum)
        raise KeyboardInterrupt

    try:  # ValueError outside the main thread: neither descriptor is left open
        old_fd = signal.set_wakeup_fd(write_fd, warn_on_full_buffer=False)
    except BaseException:
        os.close(read_fd)
        os.close(write_fd)
        raise
    old = {s: signal.signal(s, handler) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield got
    finally:
        keep_ignored = got["signal"] is not None and _AFTER_SIGNAL["ignore"]
        for s, h in old.items():
            signal.signal(s, signal.SIG_IGN if keep_ignored else h)
        if keep_ignored:  # and blocked: a signal then stays pending through the exit, even
            # where the interpreter's finalisation sets SIG_DFL back (a run stopped by
            # SIGTERM that printed its message still ended killed by a later SIGINT, -2)
            signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT, signal.SIGTERM})
        signal.set_wakeup_fd(old_fd)
        os.close(read_fd)
        os.close(write_fd)


def interrupted_status(got: dict) -> tuple[str, int]:
    """(signal name, exit status) after :func:`interrupt_signals` caught one."""
    if got.get("signal") == signal.SIGTERM:
        return "SIGTERM", EXIT_SIGTERM
    return "SIGINT", EXIT_SIGINT
