"""Every input's domain, declared once: the parser, the study loader and the docs read it.

A :class:`Domain` says what an input may be: its type (integer, number, name, list
of names, text, path, ``LOW:HIGH:N`` grid), its unit, its range (each end open or
closed, finite or not), the names it may take (matched case-insensitively, with a
"did you mean" for a misspelling), and for a list: non-empty, each name once.
From one declaration come

* the parser's ``type=`` / ``choices`` / ``nargs`` / ``metavar``
  (:meth:`Domain.argparse_kwargs`, :func:`add_option`; the action carries the
  domain as ``action.domain``, which the generated fuzz test reads);
* the check of a study file's key or a Python value (:meth:`Domain.check`);
* the table of every option's domain in ``docs/commands.md`` (:func:`option_table`,
  checked equal to the page by a test).

A value outside its domain ends as one line naming the input and the domain,
e.g. ``argument --duration: must be a number > 0 s, got 'nan'`` (exit 2).
Bounds that hold for one input together (``--tau`` / ``--dt`` delay steps, a
grid's points x realisations) stay with the command that sees them all; work
estimates are :func:`validation.cli.args.check_work`.
"""

from __future__ import annotations

import argparse
import difflib
import math
import os
import re
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from cipcore.params import MASS_RATIO_RANGE

__all__ = ["DOMAINS", "Domain", "DomainError", "add_option", "domain_of", "option_table"]

#: the kinds of input a domain declares
KINDS = ("int", "float", "bool", "name", "names", "labels", "text", "command", "grid", "in-file",
         "in-path", "out-file", "out-dir", "address")  # fmt: skip
#: A subject's label in the experiment (a recording's file name holds it): 1-32 of
#: letters, digits, ``_``, ``.``, ``-``; used with ``fullmatch`` only (``$`` would let a
#: trailing newline through).  The experiment's protocol reads it too.
LABEL = re.compile(r"[A-Za-z0-9_.-]{1,32}")


class DomainError(ValueError):
    """A value outside its domain; the message is one line without the input's name."""


def _num(x: float) -> str:
    """A bound as typed in the docs: 1e+06 as 1e6, 20.0 as 20, 2**63 - 1 in full."""
    if isinstance(x, int) and not (x >= 1e5 and str(x).rstrip("0") == "1"):
        return str(x)
    if float(x).is_integer() and abs(x) < 1e5:
        return str(int(x))
    return f"{x:g}".replace("e+0", "e").replace("e+", "e").replace("e-0", "e-")


@dataclass(frozen=True)
class Domain:
    """The declared domain of one input (module docstring).

    Parameters
    ----------
    name
        What the input is, in words (``"duration"``); the catalogue key in :data:`DOMAINS`.
    kind
        One of :data:`KINDS`.
    unit
        Unit of a number (``"s"``, ``"1/s^2"``), of a count (``"pixels"``), or ``""``.
    low, high
        Bounds of a number or count (``None``: unbounded on that side).
    low_open, high_open
        ``True`` when the bound itself is excluded.
    choices
        The names a ``name`` / ``names`` input may take, in their canonical spelling;
        matched case-insensitively. ``()`` with ``choices_of`` set: taken from it.
    suffixes
        File name endings of a path (``(".npz",)``), matched case-insensitively.
    bound
        Why ``high`` is what it is, for the message and the docs. One that spells the
        number (``"2^63 - 1"``) or is the machine's (``"4 x the cores here"``) stands in
        the docs in place of the number; any other is a reason, given after the range.
    pair
        ``nargs=2``: two values, the first lower than the second (``--beta-range``).
    item
        What one name of a ``names`` list is (``"engine"``), for the message.
    count
        ``labels``: exactly this many, each matching :data:`LABEL`, all different.
    choices_of
        A function giving the names when they are known only at run time (the engine
        registry); called when the parser is built.
    """

    name: str
    kind: str
    unit: str = ""
    low: float | None = None
    high: float | None = None
    low_open: bool = False
    high_open: bool = False
    choices: tuple[str, ...] = ()
    suffixes: tuple[str, ...] = ()
    bound: str = ""
    pair: bool = False
    choices_of: Callable[[], tuple[str, ...]] | None = None
    item: str = ""
    count: int = 0

    def __post_init__(self) -> None:
        if self.kind not in KINDS:
            raise ValueError(f"Domain {self.name}: kind must be one of {KINDS}, got {self.kind!r}")

    # ------------------------------------------------------------- words
    def names(self) -> tuple[str, ...]:
        """The allowed names (``choices``, else ``choices_of()``)."""
        if self.choices or self.choices_of is None:
            return self.choices
        return tuple(self.choices_of())

    def _spells_high(self) -> bool:
        """Whether ``bound`` spells the high end (``2^63 - 1``) or is the machine's (``4 x
        the cores here``), rather than a reason for it."""
        return self.bound[:1].isdigit() or self.bound.endswith(" here")

    def range_text(self, docs: bool = False) -> str:
        """The range in interval notation: ``(0, 1e6]``, ``>= 1``, ``finite``; with ``docs``
        a machine-dependent bound is given as its reason (``4 x the cores here``)."""
        lo, hi = self.low, self.high
        if docs and self._spells_high() and hi is not None:
            # the docs give the bound's spelling (``2^63 - 1``, ``4 x the cores here``)
            return f"{'(' if self.low_open else '['}{_num(lo)}, {self.bound}]"
        if lo is None and hi is None:
            return "finite"
        if hi is None:
            return f"{'>' if self.low_open else '>='} {_num(lo)}"
        if lo is None:
            return f"{'<' if self.high_open else '<='} {_num(hi)}"
        left, right = "(" if self.low_open else "[", ")" if self.high_open else "]"
        return f"{left}{_num(lo)}, {_num(hi)}{right}"

    def describe(self, docs: bool = False) -> str:
        """The domain in words, as messages (and with ``docs``, the docs) say it."""
        unit = f" {self.unit}" if self.unit and self.kind in ("int", "float", "grid") else ""
        bound = f" ({self.bound})" if self.bound and not (docs and self._spells_high()) else ""
        if self.kind == "int":
            rng = self.range_text(docs)
            text = f"an integer {'in ' if rng[0] in '[(' else ''}{rng}{unit}{bound}"
        elif self.kind == "float":
            rng = self.range_text(docs)
            text = (f"a finite number{unit}" if rng == "finite" else
                    f"a number {'in ' if rng[0] in '[(' else ''}{rng}{unit}{bound}")  # fmt: skip
        elif self.kind == "bool":
            text = "true or false"
        elif self.kind == "name":
            text = f"one of {', '.join(self.names())}"
        elif self.kind == "names":
            text = f"a comma list of {', '.join(self.names())} (non-empty, each once)"
        elif self.kind == "labels":
            text = (f"{self.count} different {self.item or 'label'}s separated by a comma, each "
                    "1-32 of A-Z a-z 0-9 _ . -")  # fmt: skip
        elif self.kind == "grid":
            text = (f"LOW:HIGH:N, {self.range_text()}{unit}, LOW < HIGH, N an integer in "
                    "[2, 10000]")  # fmt: skip
        elif self.kind == "address":
            text = "an address SCHEME://HOST:PORT (port in [1, 65535])"
        elif self.kind == "text":
            text = "a non-empty text"
        elif self.kind == "command":
            text = "a command line (program and arguments, shell quoting)"
        else:
            what = {"in-file": "an existing file", "in-path": "an existing file or directory",
                    "out-file": "a file to write",
                    "out-dir": "a directory to write in"}[self.kind]  # fmt: skip
            text = what + (f" ({' or '.join(self.suffixes)})" if self.suffixes else "")
        return text + (", two values LOW < HIGH" if self.pair else "")

    # ------------------------------------------------------------ values
    def parse(self, text: str) -> Any:
        """The value of command-line ``text``; :class:`DomainError` when outside the domain."""
        text = str(text)
        if self.kind == "int":
            return self.check(_int(text, self))
        if self.kind == "float":
            try:
                value = float(text.strip())
            except ValueError:
                raise DomainError(f"must be {self.describe()}, got {text!r}") from None
            return self.check(value)
        if self.kind == "names":
            items = [t.strip() for t in text.split(",")]
            if not text.strip() or any(not t for t in items):
                raise DomainError(f"must be {self.describe()}, got {text!r} (an empty name)")
            return self.check(items)
        if self.kind == "grid":
            return self._grid(text)
        if self.kind == "labels":
            return self.check([t.strip() for t in text.split(",")])
        return self.check(text)

    def check(self, value: Any) -> Any:
        """``value`` (already typed: a TOML or Python value) in its canonical form, or
        :class:`DomainError`."""
        if self.kind in ("int", "float"):
            return self._number(value)
        if self.kind == "name":
            return self._name(value)
        if self.kind == "bool":
            if not isinstance(value, bool):
                raise DomainError(f"must be {self.describe()}, got {value!r}")
            return value
        if self.kind == "names":
            return self._list(value)
        if self.kind == "labels":
            return self._labels(value)
        if not isinstance(value, str) or not value.strip():
            raise DomainError(f"must be {self.describe()}, got {value!r}")
        if self.kind == "address":
            return _address(value, self)
        if self.kind == "command":
            return _command(value, self)
        if self.kind in ("in-file", "in-path", "out-file", "out-dir"):
            return _path(value, self)
        return value

    def _number(self, value: Any) -> int | float:
        integer = self.kind == "int"
        ok_type = isinstance(value, int) if integer else isinstance(value, int | float)
        if isinstance(value, bool) or not ok_type:
            raise DomainError(f"must be {self.describe()}, got {value!r}")
        if not integer and not math.isfinite(value):
            raise DomainError(f"must be {self.describe()}, got {value!r}")
        lo, hi = self.low, self.high
        below = lo is not None and (value <= lo if self.low_open else value < lo)
        above = hi is not None and (value >= hi if self.high_open else value > hi)
        if below or above:
            raise DomainError(f"must be {self.describe()}, got {_shown(value)}")
        return value  # as given: a study's fingerprint hashes its values

    def _name(self, value: Any) -> str:
        names = self.names()
        if not isinstance(value, str):
            raise DomainError(f"must be {self.describe()}, got {value!r}")
        folded = {n.lower(): n for n in names}
        if value.strip().lower() in folded:
            return folded[value.strip().lower()]
        close = difflib.get_close_matches(value.strip().lower(), list(folded), n=1, cutoff=0.6)
        hint = f" (did you mean {folded[close[0]]!r}?)" if close else ""
        raise DomainError(f"must be {self.describe()}, got {value!r}{hint}")

    def _list(self, value: Any) -> tuple[str, ...]:
        if isinstance(value, str) or not isinstance(value, list | tuple):
            names = ", ".join(self.names())
            raise DomainError(
                f"must be a list of {self.item or 'name'}s from {names}, got {value!r}"
            )
        if not value:
            raise DomainError(f"must be {self.describe()}, got an empty list")
        one = Domain(self.name, "name", choices=self.names())
        try:
            out = tuple(one.check(v) for v in value)
        except DomainError as exc:
            raise DomainError(f"{self.item or 'each name'} {exc}") from None
        twice = [v for i, v in enumerate(out) if v in out[:i]]
        if twice:
            raise DomainError(f"names {twice[0]!r} twice; give each once")
        return out

    def _labels(self, value: Any) -> tuple[str, ...]:
        ok = (isinstance(value, list | tuple) and len(value) == self.count
              and all(isinstance(v, str) and LABEL.fullmatch(v) for v in value)
              and len(set(value)) == len(value))  # fmt: skip
        if not ok:
            shown = ",".join(map(str, value)) if isinstance(value, list | tuple) else value
            raise DomainError(f"must be {self.describe()}, got {shown!r}")
        return tuple(value)

    def _grid(self, text: str) -> tuple[float, float, int]:
        try:
            lo, hi, n = text.split(":")
            lo_f, hi_f, n_i = float(lo), float(hi), int(n)
        except ValueError:
            raise DomainError(f"expected LOW:HIGH:N, got {text!r}") from None
        if not (math.isfinite(lo_f) and math.isfinite(hi_f) and lo_f < hi_f):
            raise DomainError(f"needs finite LOW < HIGH, got {text!r}")
        edge = Domain(self.name, "float", self.unit, self.low, self.high, self.low_open,
                      self.high_open)  # fmt: skip
        try:
            edge.check(lo_f), edge.check(hi_f)
        except DomainError:
            raise DomainError(f"LOW and HIGH must be {edge.describe()}, got {text!r}") from None
        if not 2 <= n_i <= 10_000:
            raise DomainError(f"N must be an integer in [2, 10000], got {text!r}")
        return lo_f, hi_f, n_i

    # ----------------------------------------------------------- argparse
    def converter(self) -> Callable[[str], Any]:
        """An argparse ``type=`` function: :meth:`parse`, errors as ArgumentTypeError."""

        def convert(text: str) -> Any:
            try:
                return self.parse(text)
            except DomainError as exc:
                raise argparse.ArgumentTypeError(str(exc)) from None

        convert.__name__ = self.name.replace(" ", "_")
        convert.domain = self  # type: ignore[attr-defined]
        return convert

    def argparse_kwargs(self) -> dict[str, Any]:
        """``type``, ``choices`` (a name), ``nargs`` (a pair) and ``metavar`` for add_argument."""
        kw: dict[str, Any] = {"type": self.converter()}
        if self.kind == "name":
            kw["choices"] = self.names()
            kw["metavar"] = "{" + ",".join(self.names()) + "}"
        if self.pair:
            kw["nargs"] = 2
            kw["action"] = PairAction
        return kw


class PairAction(argparse.Action):
    """``nargs=2`` values LOW HIGH: refused (one line naming the option) unless LOW < HIGH."""

    def __call__(self, parser: Any, namespace: Any, values: Any, option: Any = None) -> None:
        low, high = values
        if not low < high:
            parser.error(f"argument {option}: needs LOW < HIGH, got {_shown(low)} {_shown(high)}")
        setattr(namespace, self.dest, values)


def _shown(value: Any) -> str:
    return f"{value:g}" if isinstance(value, float) else repr(value)


def _int(text: str, domain: Domain) -> int:
    t = text.strip()
    try:
        return int(t)
    except ValueError:
        pass
    try:  # 1e3 is an integer count; 1.5 is not
        f = float(t)
    except ValueError:
        f = math.nan
    if math.isfinite(f) and f.is_integer() and abs(f) < 2**63:
        return int(f)
    raise DomainError(f"must be {domain.describe()}, got {text!r}")


_ADDRESS = re.compile(r"^(?:(?P<scheme>[a-z][a-z0-9+.-]*)://)?(?P<host>[^\s:/?#]+|\[[0-9a-fA-F:]+\])"
                      r":(?P<port>[0-9]{1,5})/?$", re.IGNORECASE)  # fmt: skip


def _address(value: str, domain: Domain) -> str:
    m = _ADDRESS.match(value.strip())
    if not m or not 1 <= int(m["port"]) <= 65535:  # Dask needs the port
        raise DomainError(f"must be {domain.describe()}, got {value!r}")
    return value.strip()


def _command(value: str, domain: Domain) -> str:
    import shlex

    try:
        words = shlex.split(value)
    except ValueError as exc:  # an unclosed quote
        raise DomainError(f"must be {domain.describe()}, got {value!r} ({exc})") from None
    if not words:
        raise DomainError(f"must be {domain.describe()}, got {value!r}")
    return value


def _path(value: str, domain: Domain) -> str:
    """Checks of a path that need no writing (the write probe is the command's)."""
    if "\x00" in value:
        raise DomainError(f"must be {domain.describe()}, got a name with a NUL byte")
    p = Path(value)
    try:  # Python 3.11's is_dir lets ENAMETOOLONG through: every lookup inside
        exists, is_dir, is_file = p.exists(), p.is_dir(), p.is_file()
    except OSError as exc:  # a name too long for the file system
        raise DomainError(f"cannot use {value!r} ({exc.strerror or exc})") from None
    if domain.kind == "in-path" and not exists:  # before the suffix: a mistyped directory
        raise DomainError(f"no such file or directory {value!r}")
    if (
        domain.suffixes
        and p.suffix.lower() not in domain.suffixes
        and not (domain.kind == "in-path" and is_dir)
    ):
        raise DomainError(f"must name a {' or '.join(domain.suffixes)} file, got {value!r}")
    if domain.kind == "in-file" and not is_file:
        if is_dir:
            raise DomainError(f"{value!r} is a directory, expected a file")
        raise DomainError(f"no such file {value!r}")
    if domain.kind == "out-file" and is_dir:
        raise DomainError(f"{value!r} is a directory, expected a file")
    if domain.kind == "out-dir" and exists and not is_dir:
        raise DomainError(f"{value!r} exists and is not a directory")
    return value


def max_workers() -> int:
    """The most threads or processes a command takes: 4 per core of this machine."""
    return 4 * (os.cpu_count() or 1)


def _engine_names() -> tuple[str, ...]:
    from cipcore.registry import engine_names

    return engine_names()


def _model_names() -> tuple[str, ...]:
    from cipcore.models import MODEL_NAMES

    return MODEL_NAMES


def _profile_names() -> tuple[str, ...]:
    from validation.profiles import PROFILES

    return tuple(PROFILES)


#: the metrics a study can ask for (``metrics = [...]`` of a study file; the names of
#: :data:`validation.sweeps.study.METRICS`, declared here with the other domains)
STUDY_METRICS = ("lambda1", "rms", "max_angle", "agreement", "tau_hat", "slopes")


def _metric_names() -> tuple[str, ...]:
    return STUDY_METRICS


def _task_engines() -> tuple[str, ...]:
    from validation.experiment.task import ENGINES

    return tuple(ENGINES)


def _steppers() -> tuple[str, ...]:
    from cipcore.params import STEPPERS

    return STEPPERS


#: MuJoCo's integrator names, as the MJCF spells them
INTEGRATORS = ("Euler", "implicit", "implicitfast", "RK4")

_W = "4 x the cores here"
#: Every declared domain, by name.  Bounds without a physical reason are stated costs:
#: --realizations 1e6, --tau 10 s (the delay buffer holds tau/dt states per realisation).
DOMAINS: dict[str, Domain] = {d.name: d for d in (
    Domain("beta", "float", "1/s^2", 0.0),
    Domain("alpha", "float", "1/s^2", 0.0),
    Domain("gamma", "float", "1/s", 0.0),
    Domain("nu", "float", "s^1/2", 0.0),
    Domain("tau", "float", "s", 0.0, 10.0, low_open=True),
    Domain("dt", "float", "s", 1e-7, 0.1),
    Domain("duration", "float", "s", 0.0, low_open=True),
    Domain("realizations", "int", "", 1, 1_000_000),
    Domain("study realizations", "int", "", 2, 1_000_000),
    Domain("case realizations", "int", "", 2, 1000, bound="a case file holds 240 kB of draws each"),
    Domain("seed", "int", "", 0, 2**63 - 1, bound="2^63 - 1"),
    Domain("realization", "int", "", 0, 999_999),
    Domain("workers", "int", "", 1, max_workers(), bound=_W),
    Domain("amplitude", "float", "m"),
    Domain("rod length", "float", "m", 0.0, 100.0, low_open=True),
    Domain("mass ratio", "float", "", *MASS_RATIO_RANGE),  # m/M (cipcore.params)
    Domain("decimate", "int", "", 1, 1_000_000),
    Domain("fps", "float", "1/s", 0.0, 1000.0, low_open=True),
    Domain("pixels", "int", "pixels", 1, 4096),
    Domain("roots", "int", "", 1, 100),
    Domain("gains", "int", "", 2, 1000),
    Domain("target", "float", "1/s"),
    Domain("half width", "float", "1/s^2", 0.0, low_open=True),
    Domain("fraction", "float", "", 0.0, 1.0),
    Domain("z score", "float", "", 0.0),
    Domain("beta range", "float", "1/s^2", 0.0, pair=True),
    Domain("beta grid", "grid", "1/s^2", 0.0),
    Domain("tau grid", "grid", "s", 0.0, 10.0, low_open=True),
    Domain("timeout", "float", "s", 0.0, 86400.0, low_open=True),
    Domain("model", "name", choices_of=_model_names),
    Domain("engine", "name", choices_of=_engine_names),
    Domain("engines", "names", choices_of=lambda: ("all", *_engine_names()), item="engine"),
    Domain("integrator", "name", choices=INTEGRATORS),
    Domain("stepper", "name", choices_of=_steppers),
    Domain("profile", "name", choices_of=_profile_names),
    Domain("baseline mode", "name", choices=("auto", "exact", "roundoff", "statistical")),
    Domain("metrics", "names", choices_of=_metric_names, item="metric"),
    Domain("compare", "names", choices_of=_model_names, item="model"),
    Domain("text", "text"),
    Domain("switch", "bool"),
    Domain("command", "command"),
    Domain("address", "address"),
    Domain("npz out", "out-file", suffixes=(".npz",)),
    Domain("json out", "out-file", suffixes=(".json",)),
    Domain("xml out", "out-file", suffixes=(".xml",)),
    Domain("plot out", "out-file", suffixes=(".png", ".pdf", ".svg")),
    Domain("video out", "out-file", suffixes=(".gif", ".mp4")),
    Domain("csv out", "out-file", suffixes=(".csv",)),
    Domain("out dir", "out-dir"),
    Domain("npz in", "in-file", suffixes=(".npz",)),
    Domain("json in", "in-file"),
    Domain("mjcf in", "in-file"),
    Domain("dataset", "in-path", suffixes=(".nc",)),
    # the experiment (paper section 4)
    Domain("port", "int", "", 0, 65535),
    Domain("host", "text"),
    Domain("countdown", "int", "s", 0, 60),
    Domain("trials", "int", "", 1, 10_000, bound="each trial writes one recording per subject"),
    # a trial's recording is held in memory until it ends: about 2 kB per 20 ms frame
    Domain("trial duration", "float", "s", 0.0, 3600.0, low_open=True,
           bound="an hour: the recording is held in memory, about 2 kB a frame"),
    Domain("bot tau", "float", "s", 0.001, 10.0, bound="at least the task's 1 ms step"),
    Domain("task mode", "name", choices=("single", "coupled", "both")),
    Domain("task engine", "name", choices_of=_task_engines),
    Domain("subjects", "labels", count=2, item="subject label"),
)}  # fmt: skip


def add_option(
    parser: argparse.ArgumentParser, *flags: str, domain: str | Domain, **kwargs: Any
) -> argparse.Action:
    """``parser.add_argument(*flags, **kwargs)`` with the type, choices and nargs of
    ``domain`` (a :data:`DOMAINS` key or a :class:`Domain`); the action keeps the domain
    as ``action.domain``."""
    d = DOMAINS[domain] if isinstance(domain, str) else domain
    kw = d.argparse_kwargs()
    if "metavar" in kwargs:
        kw.pop("metavar", None)
    action = parser.add_argument(*flags, **kw, **kwargs)
    action.domain = d  # type: ignore[attr-defined]
    return action


def domain_of(action: argparse.Action) -> Domain | None:
    """The domain declared for an argparse action (its own, or its ``type``'s)."""
    return getattr(action, "domain", None) or getattr(action.type, "domain", None)


def check_key(where: str, key: str, value: Any, domain: str | Domain) -> Any:
    """A study file's (or Python) ``value`` of ``key`` in its domain, or a one-line
    :class:`cipcore.params.ParameterError` naming ``where`` and ``key``."""
    from cipcore.params import ParameterError

    d = DOMAINS[domain] if isinstance(domain, str) else domain
    try:
        return d.check(value)
    except DomainError as exc:
        raise ParameterError(f"{where}{key} {exc}") from None


def option_table(rows: list[tuple[str, str, argparse.Action]]) -> str:
    """A Markdown table of ``(command, option, action)`` rows: each option's domain.

    Options without a declared domain (flags) are left out.
    """
    lines = ["| command | option | domain |", "|---|---|---|"]
    for command, option, action in rows:
        d = domain_of(action)
        if d is None:
            continue
        text = d.describe(docs=True).replace("|", "\\|")
        lines.append(f"| `{command}` | `{option}` | {text} |")
    return "\n".join(lines)
