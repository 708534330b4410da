"""A fuzz test generated from the parser: every subcommand, every option, the study schema.

The parser is built as ``cip-validate`` builds it (:func:`validation.cli.main.build_parser`,
every command registered); the test walks it and, for each option, reads the domain
declared for it (``action.domain``, :mod:`validation.cli.domains`), or, for an option
declared only by argparse, its ``type`` and ``choices``.  Hypothesis draws values from
each domain and its edges (empty, NaN, +-inf, negative, zero, huge, unicode, a
directory where a file is expected, a file where a directory is, a missing path, a
repeated option) and runs the command in a child process (forked from this one, so that
the command modules are imported once; its own process group, its own working and
temporary directories, stdout and stderr in files) with a time budget.  It asserts:

* a value outside its declared domain: exit 2, exactly one stderr line
  ``cip-validate: error: ...`` naming the option;
* any input: no traceback, exit status in {0, 1, 2, 3, 4}, one line when 2;
* nothing written outside ``--out`` (the working and temporary directories are empty
  afterwards but for the paths the command was told to write);
* no run outlives its budget without output.

Whether a value is in its domain is decided here from the declaration's fields (bounds,
names, kind), not by calling the parser's converter.  Valid values are drawn from the
cheap end of what costs time (durations, counts), and commands whose valid runs take
minutes (``run``, ``baseline``, ``engines``, ``selftest``, ``contract``, ``experiment
serve``) are parsed only, in this process, for valid values.  The study schema:
TOML files generated from :data:`validation.sweeps.study.STUDY_KEYS` and the settings,
with wrong types and values, through ``cip-validate sweep``.

Sizes come from the Hypothesis profile: ``ci`` (the default here: fixed seed, a small
budget, < 60 s) or ``--hypothesis-profile=long`` (10,000 examples), both registered in
``tests/conftest.py``.
"""

from __future__ import annotations

import argparse
import math
import os
import shlex
import signal
import sys
import tempfile
import time
import traceback
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from validation.cli.domains import Domain, domain_of
from validation.cli.main import build_parser, main

PARSER = build_parser(full=True)  # as main.py builds it, every command registered

#: the profile's example count, shared between the tests: (share of the count, floor)
SHARES = {"invalid": (0.7, 60), "valid": (0.03, 4), "repeat": (0.06, 8), "study": (0.18, 30)}
#: commands whose valid runs take over 5 s even at their cheapest (a sweep writes its report
#: and figures): run with valid values under the long profile only
SLOW_VALID = {"sweep"}
ALLOWED = {0, 1, 2, 3, 4}


def _profile() -> settings:
    name = settings.get_current_profile_name()
    return settings.get_profile("ci" if name == "default" else name)


def sized(test: str) -> settings:
    """Settings of one fuzz test: its share of the profile's examples."""
    prof = _profile()
    share, floor = SHARES[test]
    return settings(
        prof,
        max_examples=max(floor, int(prof.max_examples * share)),
        deadline=None,
        suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow,
                               HealthCheck.filter_too_much, HealthCheck.data_too_large],
    )  # fmt: skip


# ------------------------------------------------------------------ the parser walked
def _leaves() -> dict[str, argparse.ArgumentParser]:
    """Every command that runs: "lyapunov", "case export", "experiment bots", ..."""
    out, todo = {}, [([], PARSER)]
    while todo:
        words, parser = todo.pop()
        subs = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
        if not subs and words:
            out[" ".join(words)] = parser
        for a in subs:
            todo += [([*words, n], p) for n, p in a.choices.items()]
    return out


LEAVES = _leaves()

#: the cheapest valid invocation of each command ({out}: the run's output directory,
#: {file}: a regular file, {dir}: an empty directory, {npz} / {nc}: files with those names)
BASE = {
    "lyapunov": "--beta 20 --duration 0.2 --realizations 2",
    "critical-gain": "--beta-range 19 21 --duration 0.2 --realizations 2 --gains 2",
    "stability": "--beta 30 --beta-grid 0:60:3 --tau-grid 0.05:0.2:3",
    "linearize": "",
    "simulate": "--beta 20 --duration 0.05 --realizations 1 --out {out}/r.npz",
    "run": "--profile smoke --out {out}/run",
    "baseline": "--profile smoke --out {out}/b.json",
    "sweep": "--engine reduced --grid beta=20 --metrics rms --realizations 2 --duration 0.05 "
    "--workers 1 --out {out}/sw",
    "sweep-plot": "{nc} --metric rms --x beta --out {out}/p.png",
    "sweep-export": "{nc} --csv {out}/e.csv",
    "render": "--beta 20 --duration 0.1 --width 32 --height 32 --out {out}/r.gif",
    "view": "--beta 20 --duration 0.1",
    "engines": "--engines reduced --profile smoke --out {out}/e",
    "contract": "--engine reduced",
    "case export": "--out {out}/c.npz --realizations 2",
    "case run": "--case {npz} --out {out}/t.npz",
    "case check": "--case {npz} --trajectories {npz}",
    "experiment serve": "--port 0 --out {out}/x",
    "experiment analyze": "{dir} --out {out}/a",
    "experiment bots": "--out {out}/b --trials 1 --trial-duration 1 --mode single",
    "selftest": "--realizations 1",
}
#: commands whose valid runs take minutes or never end: valid values are parsed only
PARSE_ONLY = {"run", "baseline", "engines", "selftest", "contract", "experiment serve"}
#: the cheap end of the options that cost time, for valid values
CHEAP = {
    "duration": ["0.05", "0.1", "0.2"], "realizations": ["1", "2", "3"], "gains": ["2", "3"],
    "realization": ["0", "1"], "width": ["16", "33"], "height": ["16", "33"],
    "trials": ["1"], "trial_duration": ["0.5", "1"], "roots": ["1", "7", "100"],
    "beta_grid": ["0:60:2", "10:20:3"], "tau_grid": ["0.05:0.1:2", "0.01:10:3"],
    "engine": ["reduced", "REDUCED", "mujoco"], "engines": ["reduced", "Reduced"],
    "scheduler": None, "engine_cmd": None, "threads": ["1", "2"], "workers": ["1"],
}  # fmt: skip


def test_every_command_has_a_base_invocation():
    assert set(BASE) == set(LEAVES)


def _options(command: str) -> list[argparse.Action]:
    return [a for a in LEAVES[command]._actions
            if not isinstance(a, argparse._HelpAction | argparse._VersionAction)]  # fmt: skip


OPTIONS = [(c, a) for c in sorted(LEAVES) for a in _options(c)]


def _name(action: argparse.Action) -> str:
    return action.option_strings[0] if action.option_strings else action.dest


# ---------------------------------------------------------- the places a run sees
@pytest.fixture(scope="module")
def places(tmp_path_factory) -> dict[str, str]:
    root = tmp_path_factory.mktemp("fuzz")
    f = root / "a_file"
    f.write_text("a regular file")
    (root / "empty").mkdir()
    npz = root / "x.npz"
    npz.write_bytes(b"not a zip")
    nc = root / "sweep.nc"
    nc.write_bytes(b"not a dataset")
    return {"root": str(root), "file": str(f), "dir": str(root / "empty"),
            "missing": str(root / "no" / "such"), "npz": str(npz), "nc": str(nc)}  # fmt: skip


# ------------------------------------------------------------------ the child process
@dataclass
class Outcome:
    code: int | None
    out: str
    err: str
    seconds: float
    timed_out: bool
    left_behind: bool


def _child(argv: list[str], cwd: str, tmp: str, out: str, err: str) -> None:
    """In the forked child: run ``cip-validate argv`` as its console script would."""
    code = 1
    try:
        os.setpgid(0, 0)
        os.chdir(cwd)
        os.environ["TMPDIR"] = tmp
        tempfile.tempdir = None
        null = os.open(os.devnull, os.O_RDONLY)
        os.dup2(null, 0)
        for fd, path in ((1, out), (2, err)):
            f = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
            os.dup2(f, fd)
            os.close(f)
        sys.stdout = open(1, "w", encoding="utf-8", closefd=False)
        sys.stderr = open(2, "w", encoding="utf-8", errors="backslashreplace", closefd=False)
        signal.signal(signal.SIGINT, signal.default_int_handler)
        signal.signal(signal.SIGTERM, signal.SIG_DFL)
        code = main(argv)
    except SystemExit as exc:
        code = exc.code if isinstance(exc.code, int) else 0 if exc.code is None else 1
    except BaseException:  # what the console script would show: a traceback, status 1
        traceback.print_exc()
        code = 1
    finally:
        for s in (sys.stdout, sys.stderr):
            try:
                s.flush()
            except Exception:
                pass
        os._exit(code & 0xFF if isinstance(code, int) else 1)


def run_cli(argv: list[str], work: Path, budget: float) -> Outcome:
    """Run ``argv`` in a forked child in ``work/cwd`` with ``work/tmp`` as TMPDIR."""
    for d in ("cwd", "tmp", "io"):
        (work / d).mkdir(parents=True, exist_ok=True)
    out, err = work / "io" / "out", work / "io" / "err"
    t = time.monotonic()
    pid = os.fork()
    if pid == 0:
        _child(argv, str(work / "cwd"), str(work / "tmp"), str(out), str(err))
    timed_out, status, pause = False, 0, 0.002
    while True:
        done, status = os.waitpid(pid, os.WNOHANG)
        if done:
            break
        if time.monotonic() - t > budget:
            timed_out = True
            os.killpg(pid, signal.SIGKILL)
            _, status = os.waitpid(pid, 0)
            break
        time.sleep(pause)
        pause = min(0.05, pause * 1.5)
    left = _group_alive(pid)
    if left:  # anything still in the child's process group is left behind
        os.killpg(pid, signal.SIGKILL)
    code = os.waitstatus_to_exitcode(status) if not timed_out else None
    read = lambda p: p.read_text(errors="replace") if p.exists() else ""  # noqa: E731
    o = Outcome(code, read(out), read(err), time.monotonic() - t, timed_out, left)
    if os.environ.get("CIPVAL_FUZZ_LOG"):  # one line per run: status, seconds, argv
        with open(os.environ["CIPVAL_FUZZ_LOG"], "a") as log:
            log.write(f"{o.code}\t{o.seconds:.2f}\t{shlex.join(argv)!r}\n")
    return o


def _count(test: str) -> None:
    """One line per example in ``$CIPVAL_FUZZ_LOG`` (how many a long run drew)."""
    if os.environ.get("CIPVAL_FUZZ_LOG"):
        with open(os.environ["CIPVAL_FUZZ_LOG"], "a") as log:
            log.write(f"example\t{test}\n")


def _group_alive(pgid: int, wait: float = 2.0) -> bool:
    """Whether a process of group ``pgid`` still lives ``wait`` s after its leader ended
    (killed descendants need a moment to be reaped)."""
    end = time.monotonic() + wait
    while True:
        try:
            os.killpg(pgid, 0)
        except ProcessLookupError:
            return False
        if time.monotonic() > end:
            return True
        time.sleep(0.05)


def check_outcome(o: Outcome, argv: list[str], work: Path, writes: list[str]) -> None:
    """What every run must hold (module docstring)."""
    shown = shlex.join(argv)
    assert "Traceback" not in o.err, (shown, o.err[-3000:])
    assert not o.left_behind, (shown, "a process of the run outlived it")
    if o.timed_out:
        assert o.out.strip() or o.err.strip(), (shown, f"no output in {o.seconds:.0f} s")
        return
    assert o.code in ALLOWED, (shown, o.code, o.err[-2000:])
    if o.code == 2:
        lines = [ln for ln in o.err.splitlines() if ln.strip()]
        assert len(lines) == 1 and lines[0].startswith("cip-validate: error: "), (shown, o.err)
    for d in ("cwd", "tmp"):
        left = [p for p in (work / d).rglob("*") if not _inside(p, work / "cwd", writes)]
        assert not left, (shown, f"written outside --out: {left[:5]}")


def _inside(path: Path, cwd: Path, writes: list[str]) -> bool:
    for w in writes:
        target = (cwd / w).resolve() if not os.path.isabs(w) else Path(w).resolve()
        p = path.resolve()
        if p == target or target in p.parents or p in target.parents:
            return True
    return False


# ------------------------------------------------------------------ the oracle
def _float(text: str) -> float | None:
    try:
        return float(text.strip())
    except ValueError:
        return None


def _in_range(d: Domain, v: float) -> bool:
    if d.low is not None and (v <= d.low if d.low_open else v < d.low):
        return False
    return not (d.high is not None and (v >= d.high if d.high_open else v > d.high))


def _int_ok(d: Domain, text: str) -> bool:
    try:
        v = int(text.strip())
    except ValueError:
        f = _float(text)
        if f is None or not math.isfinite(f) or not f.is_integer() or abs(f) >= 2**63:
            return False
        v = int(f)
    return _in_range(d, v)


def _path_ok(d: Domain, text: str) -> bool:
    try:
        return _path_lookup_ok(d, text)
    except OSError:  # a name the system cannot look up (too long: ENAMETOOLONG): unusable
        return False


def _path_lookup_ok(d: Domain, text: str) -> bool:
    """:func:`_path_ok`'s lookups (each may raise OSError: Python 3.11's ``is_dir`` lets
    ENAMETOOLONG through)."""
    p = Path(text)
    if not text.strip():
        return False
    if (
        d.suffixes
        and p.suffix.lower() not in d.suffixes
        and not (d.kind == "in-path" and p.is_dir())
    ):
        return False
    test = {"in-file": p.is_file, "in-path": p.exists, "out-file": lambda: not p.is_dir(),
            "out-dir": lambda: not p.exists() or p.is_dir()}[d.kind]  # fmt: skip
    return test()


def declared_valid(d: Domain, text: str) -> bool | None:
    """Is ``text`` in domain ``d``, from its fields (None: the domain does not say)."""
    if d.kind == "int":
        return _int_ok(d, text)
    if d.kind == "float":
        v = _float(text)
        return v is not None and math.isfinite(v) and _in_range(d, v)
    if d.kind == "name":
        return text.strip().lower() in {n.lower() for n in d.names()}
    if d.kind == "names":
        items = [t.strip().lower() for t in text.split(",")]
        names = {n.lower() for n in d.names()}
        return all(items) and set(items) <= names and len(set(items)) == len(items)
    if d.kind == "labels":  # d.count different labels, each of 1-32 [A-Za-z0-9_.-]
        items = [t.strip() for t in text.split(",")]
        ok = all(len(t) <= 32 and t and all(c.isascii() and (c.isalnum() or c in "_.-")
                                            for c in t) for t in items)  # fmt: skip
        return ok and len(items) == d.count and len(set(items)) == len(items)
    if d.kind == "grid":
        parts = text.split(":")
        if len(parts) != 3 or not _int_ok(Domain("n", "int", low=2, high=10_000), parts[2]):
            return False
        lo, hi = _float(parts[0]), _float(parts[1])
        edge = Domain("edge", "float", "", d.low, d.high, d.low_open, d.high_open)
        return (None not in (lo, hi) and math.isfinite(lo) and math.isfinite(hi) and lo < hi
                and _in_range(edge, lo) and _in_range(edge, hi))  # fmt: skip
    if d.kind == "text":
        return bool(text.strip())
    if d.kind == "command":  # not blank (Python's whitespace, \x1c-\x1f too), then shlex
        try:
            return bool(text.strip()) and bool(shlex.split(text))
        except ValueError:
            return False
    if d.kind in ("in-file", "in-path", "out-file", "out-dir"):
        return _path_ok(d, text)
    if d.kind == "address":  # [SCHEME://]HOST:PORT, the port in [1, 65535]
        rest, _, port = text.strip().removesuffix("/").rpartition(":")
        scheme, sep, host = rest.rpartition("://")
        ok_scheme = not sep or (scheme[:1].isascii() and scheme[:1].isalpha() and all(
            c.isascii() and (c.isalnum() or c in "+.-") for c in scheme))  # fmt: skip
        six = host.startswith("[") and host.endswith("]") and len(host) > 2 and all(
            c in "0123456789abcdefABCDEF:" for c in host[1:-1])  # fmt: skip
        plain = bool(host) and not any(c in host for c in ":/?#[]") and not any(
            c.isspace() for c in host)  # fmt: skip
        ok_port = port.isascii() and port.isdigit() and len(port) <= 5
        return ok_scheme and (six or plain) and ok_port and 1 <= int(port) <= 65535
    return None


def plain_valid(action: argparse.Action, text: str) -> bool | None:
    """An option declared by argparse alone: its type and choices say what is invalid."""
    if action.choices is not None and text not in action.choices:
        return False
    if action.type in (int, float):
        try:
            action.type(text)
        except ValueError:
            return False
    return None


# ------------------------------------------------------------------ the values
EDGES = ["", " ", "nan", "NaN", "inf", "-inf", "1e999", "-1", "0", "-0", "1e308", "-1e308",
         "99999999999999999999999", "1.5", "abc", "\u221e", "\u0661\u0662", "\u00e9t\u00e9",
         "\udcff", "0x10", "1e3", "--", "-x", ",", "a,,b", "1:2", "a:b:c", "0:1:1",
         "nan:1:3", "2:1:3"]  # fmt: skip


def _domain_values(d: Domain, places: dict[str, str]) -> st.SearchStrategy[str]:
    if d.kind == "int":
        lo = int(d.low) if d.low is not None else -(10**6)
        hi = int(d.high) if d.high is not None else 10**6
        inside = st.integers(lo, hi).map(str)
        edges = [str(lo - 1), str(hi + 1), str(lo), str(hi), str(10**30), str(-(10**30))]
        return st.one_of(inside, st.sampled_from(edges))
    if d.kind == "float":
        return st.one_of(st.floats(allow_nan=True, allow_infinity=True).map(repr),
                         st.floats(min_value=-1e3, max_value=1e3).map(repr),
                         st.sampled_from([repr(x) for x in (d.low, d.high) if x is not None]
                                         or ["0"]))  # fmt: skip
    if d.kind in ("name", "names"):
        names = list(d.names())
        pick = st.sampled_from(names)
        one = st.one_of(pick, pick.map(str.swapcase), pick.map(lambda n: n[:-1] or "x"),
                        pick.map(lambda n: n + "x"))  # fmt: skip
        if d.kind == "name":
            return one
        return st.lists(one, min_size=1, max_size=3).map(",".join)
    if d.kind == "labels":
        label = st.one_of(st.sampled_from(["A", "B", "b", "s1.x", "-", "a" * 32, "a" * 33]),
                          st.text(max_size=4))  # fmt: skip
        return st.lists(label, min_size=0, max_size=3).map(",".join)
    if d.kind == "grid":
        return st.tuples(st.floats(-1, 100), st.floats(-1, 100), st.integers(0, 20001)).map(
            lambda t: f"{t[0]!r}:{t[1]!r}:{t[2]}"
        )
    if d.kind in ("in-file", "in-path", "out-file", "out-dir"):
        names = [places["file"], places["dir"], places["missing"], places["npz"], places["nc"],
                 f"{places['file']}/under.npz", "rel/out", "x.npz", "x.JSON", "x.csv",
                 "x.png", "x.gif", "x.xml", "x.txt",
                 places["root"] + "/" + "\u00e9" * 300]  # fmt: skip
        return st.sampled_from(names)
    return st.text(min_size=0, max_size=12).filter(lambda s: "\x00" not in s)


def values_for(action: argparse.Action, places: dict[str, str]) -> st.SearchStrategy[str]:
    d = domain_of(action)
    if d is not None and d.pair:
        one = st.one_of(_domain_values(d, places), st.sampled_from(EDGES[2:13]))
        return st.tuples(one, one).map(" ".join)
    base = _domain_values(d, places) if d is not None else st.text(max_size=10)
    if action.choices is not None and d is None:
        base = st.one_of(base, st.sampled_from(list(action.choices)))
    return st.one_of(base, st.sampled_from(EDGES)).filter(lambda s: "\x00" not in s)


def expected_valid(action: argparse.Action, text: str) -> bool | None:
    if text == "--" and action.nargs != 0 and action.option_strings:  # end of options
        return False
    if not action.option_strings and text.startswith("-"):
        return None  # a positional that looks like an option: argparse's reading, undeclared
    d = domain_of(action)
    if d is not None and d.pair:  # two numbers, each in the domain, LOW < HIGH
        words = text.split(" ")
        one = Domain(d.name, d.kind, d.unit, d.low, d.high, d.low_open, d.high_open)
        if len(words) != 2 or not all(declared_valid(one, w) for w in words):
            return False
        return float(words[0]) < float(words[1])
    return declared_valid(d, text) if d is not None else plain_valid(action, text)


# ------------------------------------------------------------------ building argv
def base_argv(command: str, places: dict[str, str], out: Path) -> list[str]:
    text = BASE[command].format(out=out, **places)
    return [*command.split(), *shlex.split(text)]


def with_value(argv: list[str], command: str, action: argparse.Action, value: str) -> list[str]:
    """``argv`` with ``action`` set to ``value`` (replacing the base's value)."""
    n = len(command.split())
    head, rest = argv[:n], argv[n:]
    if not action.option_strings:  # a positional: the base's first word not an option
        idx = next((i for i, w in enumerate(rest) if not w.startswith("-")), None)
        if idx is None or (idx > 0 and rest[idx - 1].startswith("-")):
            return [*head, value, *rest]
        return [*head, *rest[:idx], value, *rest[idx + 1 :]]
    rest = _without(rest, action)
    if action.nargs == 0:
        return [*head, *rest, action.option_strings[0]]
    if action.nargs == 2:  # a pair: two words
        return [*head, *rest, action.option_strings[0], *value.split(" ", 1)]
    return [*head, *rest, f"{action.option_strings[0]}={value}"]


def _without(words: list[str], action: argparse.Action) -> list[str]:
    out, skip = [], 0
    for w in words:
        if skip:
            skip -= 1
            continue
        if w in action.option_strings:
            skip = 0 if action.nargs == 0 else action.nargs if isinstance(action.nargs, int) else 1
            continue
        if w.split("=", 1)[0] in action.option_strings:
            continue
        out.append(w)
    return out


def writes_of(argv: list[str]) -> list[str]:
    """Paths the command was told to write (each --out, --csv, --junit; run dirs)."""
    out = []
    for i, w in enumerate(argv):
        opt, eq, val = w.partition("=")
        if opt in ("--out", "--csv", "--junit", "--plot"):
            out.append(val if eq else argv[i + 1] if i + 1 < len(argv) else "")
    return [w for w in out if w]


# ------------------------------------------------------------------ the tests
def _work(places: dict[str, str]) -> Path:
    return Path(tempfile.mkdtemp(dir=places["root"], prefix="run-"))


def _check_invalid(o: Outcome, argv: list[str], action: argparse.Action) -> None:
    lines = [ln for ln in o.err.splitlines() if ln.strip()]
    assert o.code == 2, (shlex.join(argv), o.code, o.err[-2000:])
    assert len(lines) == 1, (shlex.join(argv), o.err)
    names = [*action.option_strings, action.dest, str(action.metavar)]
    assert any(n in lines[0] for n in names), (shlex.join(argv), lines[0])


@sized("invalid")
@given(data=st.data(), pick=st.sampled_from(OPTIONS))
@example(data=None, pick=("sweep", "--workers", "100000"))
@example(data=None, pick=("simulate", "--integrator", "rk5"))
@example(data=None, pick=("lyapunov", "--tau", "11"))
@example(data=None, pick=("experiment bots", "--trials", "0"))
@example(data=None, pick=("experiment serve", "--port", "99999"))
@example(data=None, pick=("experiment bots", "--subjects", "A,A"))
@example(data=None, pick=("experiment bots", "--trial-duration", "1e4"))  # long: ran > 60 s
@example(data=None, pick=("selftest", "--faults", "gravity,Gravity"))
@example(data=None, pick=("sweep", "--scheduler", "nope:99999"))
@example(data=None, pick=("engines", "--engines", "reduced,Reduced"))
@example(data=None, pick=("contract", "--engine-cmd", "'unclosed"))
@example(data=None, pick=("simulate", "--amplitude", "\udcff"))
@example(data=None, pick=("sweep", "--metrics", "rms,,rms"))
@example(data=None, pick=("case export", "--realizations", "1001"))
@example(data=None, pick=("experiment bots", "--out", ""))  # long run: wrote into the cwd
@example(data=None, pick=("sweep", "--scheduler", "0"))  # long run: Dask's traceback
@example(data=None, pick=("run", "--workers", "--"))  # long run: argparse stored [], ran
@example(data=None, pick=("experiment serve", "--out", "--"))  # long run: the oracle's
@example(data=None, pick=("case export", "--mjcf", "/tmp/" + "\u00e9" * 300))  # ENAMETOOLONG
@example(data=None, pick=("baseline", "--engine-cmd", "\x1f"))  # long run: the oracle's blank
@example(data=None, pick=("sweep-export", "dataset", "/tmp/" + "\u00e9" * 300))  # is_dir raised
def test_declared_invalid_values_are_one_line_exit_2(places, data, pick):
    """A value outside its declared domain: exit 2, one line naming the option; every
    value: no traceback, an allowed status, nothing written outside --out."""
    if data is None:  # an explicit example: (command, option, value)
        command, flag, value = pick  # an option's flag, or a positional's dest
        action = next(a for a in _options(command) if flag in (*a.option_strings, a.dest))
    else:
        command, action = pick
        value = data.draw(values_for(action, places), label=_name(action))
    work = _work(places)
    argv = with_value(base_argv(command, places, work / "out"), command, action, value)
    _count("invalid")
    with _in(work / "cwd"):
        valid = expected_valid(action, value)
        if valid is not False and _not_run(command, action, value, valid):
            accepted = _parses(argv)
            assert accepted or not valid, (shlex.join(argv), "a declared-valid value refused")
            if accepted:
                return
    o = run_cli(argv, work, budget=60.0)
    check_outcome(o, argv, work, writes_of(argv))
    if valid is False:
        _check_invalid(o, argv, action)


def _not_run(command: str, action: argparse.Action, value: str, valid: bool | None) -> bool:
    """A value the parser takes that this test leaves to the valid-value test (module
    docstring): every value of a command that runs for minutes, a declared-valid value,
    a flag."""
    return command in PARSE_ONLY or bool(valid) or action.nargs == 0


@contextmanager
def _in(directory: Path):
    """Paths of the oracle read as the child reads them: relative to its working directory."""
    (directory).mkdir(parents=True, exist_ok=True)
    here = os.getcwd()
    os.chdir(directory)
    try:
        yield
    finally:
        os.chdir(here)


def _parses(argv: list[str]) -> bool:
    """Whether the parser takes ``argv`` (in this process; its error is swallowed)."""
    import contextlib
    import io

    try:
        with contextlib.redirect_stderr(io.StringIO()):
            ns = build_parser(argv[0]).parse_args(argv)
    except SystemExit:
        return False
    return ns.func is not None


NOT_RUN = PARSE_ONLY | (set() if settings.get_current_profile_name() == "long" else SLOW_VALID)


@sized("valid")
@given(data=st.data(), pick=st.sampled_from(
    [(c, a) for c, a in OPTIONS if c not in NOT_RUN and a.dest in CHEAP and CHEAP[a.dest]]
    + [(c, a) for c, a in OPTIONS if c not in NOT_RUN and a.dest not in CHEAP
       and domain_of(a) is not None
       and domain_of(a).kind in ("int", "float", "name")]))  # fmt: skip
def test_valid_values_of_cheap_runs_finish_without_a_traceback(places, data, pick):
    """Valid values (the cheap end of anything that costs time): the command runs to an
    allowed status within its budget, or prints progress; never a traceback."""
    command, action = pick
    d = domain_of(action)
    if action.dest in CHEAP:
        value = data.draw(st.sampled_from(CHEAP[action.dest]), label=_name(action))
    else:
        value = data.draw(_valid_values(d), label=_name(action))
    work = _work(places)
    argv = with_value(base_argv(command, places, work / "out"), command, action, value)
    o = run_cli(argv, work, budget=60.0)
    check_outcome(o, argv, work, writes_of(argv))


def _valid_values(d: Domain) -> st.SearchStrategy[str]:
    """Values inside an int, float or name domain, its bounds included."""
    if d.kind == "name":
        # matched case-insensitively: the canonical spelling, lower or upper case
        return st.sampled_from(list(d.names())).flatmap(
            lambda n: st.sampled_from([n, n.lower(), n.upper()])
        )
    lo = d.low if d.low is not None else -1e6
    hi = d.high if d.high is not None else 1e6
    if d.kind == "int":
        return st.integers(int(lo), int(hi)).map(str)
    inside = st.floats(lo, hi, exclude_min=d.low_open, exclude_max=d.high_open)
    huge = st.sampled_from([x for x in (1e300, -1e300) if _in_range(d, x)] or [hi])
    return st.one_of(inside, huge).map(repr)


REPEATABLE = (argparse._AppendAction, argparse._CountAction)


@sized("repeat")
@given(pick=st.sampled_from([(c, a) for c, a in OPTIONS if a.option_strings
                             and not isinstance(a, REPEATABLE)]))  # fmt: skip
def test_an_option_given_twice_is_refused(places, pick):
    command, action = pick
    work = _work(places)
    argv = base_argv(command, places, work / "out")
    opt = action.option_strings[-1]
    if action.nargs == 0:
        argv += [opt, opt]
    else:
        text = next((w for w in _value_of(argv, action)), None) or "1"
        argv += [f"{opt}={text}", f"{opt}={text}"]
    o = run_cli(argv, work, budget=30.0)
    check_outcome(o, argv, work, writes_of(argv))
    assert o.code == 2 and "given twice" in o.err and opt in o.err, (shlex.join(argv), o.err)


def _value_of(argv: list[str], action: argparse.Action) -> list[str]:
    for i, w in enumerate(argv):
        if w in action.option_strings and i + 1 < len(argv):
            return [argv[i + 1]]
    return []


# ------------------------------------------------------------------ the study schema
STUDY_BASE = {"name": '"fz"', "engine": '"reduced"', "metrics": '["rms"]',
              "realizations": "2", "duration": "0.05", "seed": "0"}  # fmt: skip
TOML_VALUES = ['"rms"', '""', '"x"', '"\u00e9"', "0", "-1", "1", "2", "2.5", "1e400", "nan",
               "inf", "-inf", "true", "[]", '["rms", "rms"]', '["RMS"]', '["rms"]',
               "[1, 2]", "{a = 1}", "1979-05-27", "1e12", '["single", "coupled"]',
               '["single"]', '"Coupled"', '"MUJOCO"', '"mujocco"',
               "9223372036854775807"]  # fmt: skip


def _study_text(study: dict[str, str], tables: dict[str, dict[str, str]]) -> str:
    parts = []
    if study is not None:
        parts.append("[study]\n" + "".join(f"{k} = {v}\n" for k, v in study.items()))
    for t, kv in tables.items():
        parts.append(f"[{t}]\n" + "".join(f"{k} = {v}\n" for k, v in kv.items()))
    return "\n".join(parts)


def _study_keys() -> list[str]:
    """Every key of the study schema (its ``[study]`` keys, the settings of ``[fixed]`` and
    ``[grid]``, the keys of ``[gain]`` and ``[stcc]``) and one that is none of them."""
    from validation.sweeps.mapping import SETTINGS
    from validation.sweeps.study import STUDY_KEYS, TABLE_KEYS

    keys = {*STUDY_KEYS, *SETTINGS, *(k for t in TABLE_KEYS.values() for k in t)}
    return [*sorted(keys), "bogus"]


def _typed_valid(d: Domain, value: object) -> bool | None:
    """Is the TOML ``value`` in the number domain ``d`` (None: not a number domain)."""
    if d.kind not in ("int", "float"):
        return None
    if isinstance(value, bool) or not isinstance(value, int | float):
        return False
    if d.kind == "int" and not isinstance(value, int):
        return False
    return math.isfinite(value) and _in_range(d, value)


@sized("study")
@given(
    where=st.sampled_from(["study", "grid", "fixed", "gain", "stcc", "missing", "unknown"]),
    key=st.sampled_from(_study_keys()),
    value=st.sampled_from(TOML_VALUES),
)  # fmt: skip
@example(where="gain", key="gains", value="1")
@example(where="stcc", key="dominance", value="2.5")
@example(where="gain", key="half_width", value="-1")
@example(where="study", key="metrics", value='"rms"')
@example(where="missing", key="name", value='"x"')
@example(where="study", key="duration", value="1e12")
@example(where="study", key="bogus", value="3")
@example(where="study", key="engine", value='"mujocco"')
def test_generated_study_files_are_one_line_exit_2_naming_the_key(places, where, key, value):
    """Study files with wrong types and values: one line naming the file and the key, no
    traceback; a valid one loads (checked in this process, not run)."""
    import tomllib

    from cipcore.params import ParameterError
    from validation.cli.domains import DOMAINS
    from validation.sweeps.study import STUDY_KEYS, TABLE_KEYS, Study

    study = dict(STUDY_BASE)
    tables = {"grid": {"beta": "[20.0]"}}
    if where == "study":
        study[key] = value
    elif where == "missing":
        study = None
    elif where == "unknown":
        tables["bogus"] = {key: value}
    else:
        tables.setdefault(where, {})[key] = value
    work = _work(places)
    _count("study")
    path = work / "study.toml"
    path.write_text(_study_text(study, tables))
    declared = TABLE_KEYS.get(where, {}).get(key)  # a [gain] / [stcc] key's domain
    try:
        typed = tomllib.loads(f"v = {value}")["v"]
    except tomllib.TOMLDecodeError:
        typed = None
    outside = declared is not None and _typed_valid(DOMAINS[declared], typed) is False
    try:
        Study.from_toml(path)
    except ParameterError as exc:
        msg = str(exc)
        assert "\n" not in msg and str(path) in msg, msg
        if outside:  # refused for its declared domain, named as table.key
            assert f"{where}.{key}" in msg, msg
        if where == "study" and key in STUDY_KEYS and "toml" not in msg.lower():
            assert key in msg, msg
        argv = ["sweep", str(path), "--out", str(work / "out" / "sw")]
        o = run_cli(argv, work, budget=60.0)
        check_outcome(o, argv, work, writes_of(argv))
        assert o.code == 2 and str(path) in o.err, (o.code, o.err)
        if where == "study" and key == "duration" and "work" in o.err:
            assert "[study] duration" in o.err and "--duration" not in o.err, o.err
        return
    assert where not in ("missing", "unknown")
    assert not outside, (where, key, value, "a value outside its declared domain loaded")
    if where == "study" and key == "duration" and value == "1e12":  # too much work
        argv = ["sweep", str(path), "--out", str(work / "out" / "sw")]
        o = run_cli(argv, work, budget=60.0)
        check_outcome(o, argv, work, writes_of(argv))
        assert o.code == 2 and "[study] duration" in o.err and "--duration" not in o.err, o.err


# ------------------------------------------------------------------ the real entry point
@pytest.mark.parametrize(
    "argv, words",
    [
        (["lyapunov", "--beta", "20", "--integrator", "rk4"], ["unrecognized"]),
        (["simulate", "--beta", "20", "--out", "r.npz", "--integrator", "rk5"],
         ["--integrator", "did you mean 'RK4'"]),
        (["sweep", "--workers", "100000"], ["--workers", "4 x the cores"]),
    ],
)  # fmt: skip
def test_the_console_script_answers_the_same(tmp_path, argv, words):
    """The installed ``cip-validate`` (a real process, not a fork): one line, exit 2."""
    import shutil
    import subprocess

    exe = shutil.which("cip-validate") or str(Path(sys.executable).parent / "cip-validate")
    r = subprocess.run([exe, *argv], cwd=tmp_path, capture_output=True, text=True, timeout=60)
    lines = r.stderr.strip().splitlines()
    assert r.returncode == 2 and len(lines) == 1 and "Traceback" not in r.stderr, r.stderr
    assert all(w in lines[0] for w in words), lines[0]
    assert not list(tmp_path.iterdir())


def test_case_insensitive_names_are_canonical():
    ns = build_parser("simulate").parse_args(
        ["simulate", "--beta", "20", "--out", "r.npz", "--integrator", "rk4", "--engine",
         "MuJoCo", "--model", "COUPLED", "--stepper", "Explicit"]
    )  # fmt: skip
    assert (ns.integrator, ns.engine, ns.model, ns.stepper) == (
        "RK4", "mujoco", "coupled", "explicit")  # fmt: skip
