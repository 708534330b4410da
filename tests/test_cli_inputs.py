"""Every bad input of the command line: exit 2, exactly one line on stderr, no traceback.

A table walks every command with bad values (each must be refused before any
work); hypothesis draws bad counts and non-numbers for the typed options.
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest
import xarray as xr
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from validation.cli.main import build_parser, main

BAD_STUDY = """[study]
name = "x"
engine = "reduced"
metrics = ["rms"]
bogus = 3
[grid]
beta = [20.0, 21.0]
"""

# (argv with {file} = a regular file, {d} = a fresh directory, {bad} = the bad study; words
# that the one-line message must contain)
CASES = [
    ("simulate --beta 20 --out {file}/run.npz", ["--out", "is not a directory"]),
    ("simulate --beta 20 --out {d}/missing/run.npz", ["--out", "does not exist"]),
    ("simulate --beta 20 --out {d}/run.txt", ["--out", ".npz"]),
    ("simulate --beta 20 --out {d}", ["--out", ".npz"]),
    ("sweep --engine reduced --grid beta=20,21 --metrics rms --out {file}/sw", ["--out"]),
    ("run --profile smoke --out {file}/out", ["--out"]),
    ("run --profile smoke --out {file}", ["--out", "not a directory"]),
    ("baseline --out {file}/b.json", ["--out"]),
    ("baseline --out {d}/b.txt", ["--out", ".json"]),
    ("stability --beta 30 --beta-grid 0:80:0", ["--beta-grid", "[2, 10000]"]),
    ("stability --beta 30 --beta-grid 80:0:5", ["--beta-grid", "LOW < HIGH"]),
    ("stability --beta 30 --beta-grid a:b", ["--beta-grid", "LOW:HIGH:N"]),
    ("stability --beta 30 --tau-grid 0:0.3:5", ["--tau-grid", "(0, 10] s"]),
    ("stability --beta 30 --roots 0", ["--roots", "[1, 100]"]),
    ("stability --beta 30 --plot {d}/x.gif", ["--plot", ".png"]),
    ("sweep --engine reduced --grid beta=abc --metrics rms --out {d}/s", ["--grid beta", "number"]),
    ("sweep --engine reduced --grid beta= --metrics rms --out {d}/s", ["--grid", "no values"]),
    ("sweep --engine reduced --grid beta --metrics rms --out {d}/s", ["--grid", "NAME="]),
    ("sweep --engine reduced --grid foo=1,2 --metrics rms --out {d}/s", ["foo", "allowed"]),
    ("sweep --engine reduced --grid beta=20 --metrics rms,max_angle", ["max_angle", "rigid"]),
    ("sweep --engine reduced --grid beta=20 --metrics speed", ["--metrics", "speed", "tau_hat"]),
    ("sweep --engine reduced --grid beta=20 --metrics rms --realizations 1", ["--realizations"]),
    ("sweep {bad}", ["bogus", "[study]"]),
    ("sweep no_such_study", ["study file"]),
    ("sweep --engine reduced --grid beta=20 --metrics rms --workers 0", ["--workers", "[1, "]),
    (
        "sweep --engine reduced --grid beta=20,21 --metrics rms --duration 1e12 --out {d}/s",
        ["--duration", "--force"],
    ),
    ("sweep-plot {d} --metric rms --x beta", ["dataset"]),
    ("simulate --beta 20 --out {d}/r.npz --threads 0", ["--threads", "[1, "]),
    ("lyapunov --beta 20 --threads -2", ["--threads", "[1, "]),
    ("simulate --beta 20 --out {d}/r.npz --duration 1e15", ["--duration", "--force", "4e+18"]),
    ("lyapunov --beta 20 --duration 1e15", ["--duration", "--force"]),
    ("critical-gain --beta-range 19 21 --duration 1e12", ["--duration", "--force"]),
    ("critical-gain --beta-range 21 19", ["--beta-range", "LOW < HIGH"]),
    ("critical-gain --beta-range 19 21 --gains 1", ["--gains", "[2, 1000]"]),
    ("lyapunov --beta 20 --engine nosuchengine", ["--engine", "reduced"]),
    ("lyapunov --beta 20 --engine mujoco --stepper explicit", ["--stepper", "rigid-body"]),
    ("simulate --beta 20 --out {d}/r.npz --decimate 0", ["--decimate", "[1, "]),
    ("simulate --beta 20 --out {d}/r.npz --model triple", ["--model", "single"]),
    ("simulate --beta 20 --out {d}/r.npz --engine mujoco --rod-length -1", ["--rod-length"]),
    ("simulate --beta 20 --out {d}/r.npz --amplitude nan", ["--amplitude", "finite"]),
    ("lyapunov --beta 20 --seed -1", ["--seed", "[0, "]),
    ("lyapunov --beta -3", ["beta"]),
    ("lyapunov --beta 20 --tau 0.1234", ["tau"]),
    ("lyapunov --beta 20 --dt -1", ["dt"]),
    ("lyapunov", ["--beta", "required"]),
    ("run --profile huge", ["--profile", "quick"]),
    ("run --workers 0", ["--workers", "[1, "]),
    ("run --baseline {d}/none.json --out {d}/o", ["--baseline", "no such file"]),
    ("run --baseline {file} --out {d}/o", ["--baseline", "not JSON"]),
    ("baseline --from {d}/none.json --out {d}/b.json", ["--from", "no such file"]),
    ("engines --engines reduced,nosuchengine", ["engine must be one of", "nosuchengine"]),
    ("engines --threads 0", ["threads", "[1, "]),
    ("engines --engines reduced --out {file}/x", ["--out"]),
    ("render --beta 20 --out {d}/run.avi", ["--out", ".gif"]),
    ("render --beta 20 --fps 0 --out {d}/run.gif", ["--fps", "(0, 1000]"]),
    ("render --beta 20 --realization -1 --out {d}/run.gif", ["--realization", "[0, "]),
    ("render --beta 20 --out {file}/run.gif", ["--out", "is not a directory"]),
    ("nosuchcommand", ["invalid choice"]),
    # options that contradict or repeat
    ("simulate --beta 20 --out {d}/a.npz --out {d}/b.npz", ["--out", "given twice"]),
    ("lyapunov --beta 20 --beta 21", ["--beta", "given twice"]),
    ("run --profile smoke --profile quick --out {d}/o", ["--profile", "given twice"]),
    (
        "sweep --engine reduced --grid beta=20,21 --grid beta=22 --metrics rms",
        ["--grid beta", "twice"],
    ),
    (
        "sweep --engine reduced --grid beta=20,21 --set beta=30 --metrics rms",
        ["--grid beta", "--set beta"],
    ),
    ("sweep --engine reduced --grid beta=20,20 --metrics rms", ["--grid beta", "twice"]),
    (
        "sweep --engine reduced --grid beta=20 --set gamma=1,2 --metrics rms",
        ["--set gamma", "one value"],
    ),
    (
        "sweep --engine reduced --grid integrator=RK4,Bogus --metrics rms",
        ["--grid integrator", "rigid-body"],
    ),
    (
        "sweep --engine reduced --grid beta=20 --set rod_length=2 --metrics rms",
        ["--set rod_length", "rigid-body"],
    ),
    (
        "sweep --engine mujoco --grid integrator=RK4,Bogus --metrics rms",
        ["--grid integrator", "Euler"],
    ),
    ("sweep --engine reduced --grid beta=20 --set tau=-1 --metrics rms", ["--set tau", "(0, 10]"]),
    # checks that can be made before work, naming the option as typed
    ("lyapunov --beta 20 --duration 0.1", ["--duration", ">= 0.112 s"]),
    ("critical-gain --beta-range 19 21 --duration 0.05", ["--duration", ">= 0.112 s"]),
    ("lyapunov --beta 20 --duration 1.0005", ["--duration", "whole number of time steps"]),
    ("render --beta 20 --duration 1e7 --out {d}/r.gif", ["--duration", "--fps", "GiB"]),
    ("render --beta 20 --width 100000 --out {d}/r.gif", ["--width", "[1, 4096]"]),
    ("selftest --realizations 0", ["--realizations", "[1, 1e6]"]),
    ("selftest --seed -1", ["--seed", "[0, "]),
    ("engines --seed -3", ["--seed", "[0, "]),
    # a user's damaged input files
    ("run --profile smoke --mjcf {d} --out {d}/o", ["--mjcf", "is a directory"]),
    (
        "run --profile smoke --mjcf {xml} --out {d}/o",
        ["--mjcf", "XML parse error", "Line number=3"],
    ),
    ("sweep-plot {nc} --metric rms --x beta --out {d}/p.png", ["dataset", "damaged"]),
    # the long fuzz run: L = g/alpha too short for MuJoCo's geom (a traceback), or too long
    ("linearize --alpha 1e300", ["alpha", "[9.81e-05, 9.81e+05] 1/s^2", "pendulum length"]),
    ("linearize --alpha 1e-300", ["alpha", "[9.81e-05, 9.81e+05] 1/s^2"]),
    ("stability --beta 1e300", ["no characteristic root", "beta 1e+300"]),
    # the fourth long run: a bob below MuJoCo's mjMINVAL was a traceback from its compiler
    ("linearize --mass-ratio 4.4e-188", ["--mass-ratio", "[1e-12, 1]"]),
    # the long run at seed 1: a step count beyond float64 was an OverflowError
    (
        "experiment bots --trials 1 --mode single --trial-duration 1e306 --out {d}/b",
        ["--trial-duration", "1e+306", "(0, 3600] s"],
    ),
    ("lyapunov --beta 20 --duration 1e306", ["--duration", "beyond any count"]),
    # the long fuzz run's later findings
    ("lyapunov --beta 1e300 --duration 0.2 --realizations 2", ["beta 1e+300", "float64"]),
    (
        "simulate --beta 20 --realizations 1000 --duration 1000 --out {d}/s.npz",
        ["--realizations", "--decimate", "GiB"],
    ),
    ("experiment bots --trials 10001 --out {d}/b", ["--trials", "[1, 10000]"]),
    (
        "experiment bots --trial-duration 3600 --trials 20 --out {d}/b",
        ["--trials x --trial-duration", "estimated work 1.08e+07 bot frames", "--force"],
    ),
    (
        "stability --beta 30 --beta-grid 0:80:1000 --tau-grid 0.01:0.3:1000 --plot {d}/x.png",
        ["--beta-grid x --tau-grid", "estimated work 1e+06 region points", "--force"],
    ),
]


def test_mujoco_warnings_are_one_stderr_line_not_a_log_file(tmp_path, monkeypatch, capfd):
    """The long fuzz run: ``linearize --gamma 1e300`` made MuJoCo append its warning to
    MUJOCO_LOG.TXT in the working directory; it is a stderr line instead (cip.model)."""
    monkeypatch.chdir(tmp_path)
    assert main(["linearize", "--gamma", "1e300", "--json"]) == 0
    err = capfd.readouterr().err
    assert "mujoco warning: Nan, Inf or huge value" in err
    assert list(tmp_path.iterdir()) == []


@pytest.fixture
def places(tmp_path):
    f = tmp_path / "a_file"
    f.write_text("not a directory and not JSON")
    d = tmp_path / "d"
    d.mkdir()
    bad = tmp_path / "bad_study.toml"
    bad.write_text(BAD_STUDY)
    xml = tmp_path / "bad.xml"
    xml.write_text("<mujoco>\n<worldbody>\n<body>\n</mujoco>\n")  # <body> never closed
    nc = tmp_path / "sweep.nc"
    xr.Dataset({"rms": (("beta",), [1.0, 2.0])}, coords={"beta": [20.0, 21.0]},
               attrs={"study": "{}", "fingerprint": "0"}).to_netcdf(nc, engine="scipy")  # fmt: skip
    nc.write_bytes(nc.read_bytes()[:-20])  # a sweep dataset cut short
    return {"file": str(f), "d": str(d), "bad": str(bad), "xml": str(xml), "nc": str(nc)}


def run(capsys, argv: list[str]) -> tuple[int, str, str]:
    code = main(argv)
    out, err = capsys.readouterr()
    return code, out, err


def assert_one_line_usage_error(code: int, err: str, words: list[str]) -> None:
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert code == 2, err
    assert len(lines) == 1, err
    assert lines[0].startswith("cip-validate: error: "), lines[0]
    assert "Traceback" not in err
    for w in words:
        assert w in lines[0], (w, lines[0])


@pytest.mark.parametrize(("argv", "words"), CASES, ids=[c[0].split(" --out")[0] for c in CASES])
def test_bad_input_is_one_line_exit_2_before_any_work(capsys, places, argv, words):
    code, out, err = run(capsys, argv.format(**places).split())
    assert_one_line_usage_error(code, err, words)
    assert out == ""


def _count_options():
    """(command argv prefix, option, minimum) for every integer count option of the CLI."""
    return [
        (["lyapunov", "--beta", "20"], "--realizations", 1),
        (["lyapunov", "--beta", "20"], "--threads", 1),
        (["critical-gain", "--beta-range", "19", "21"], "--gains", 2),
        (["stability", "--beta", "30"], "--roots", 1),
        (["run"], "--workers", 1),
        (["sweep", "--engine", "reduced", "--grid", "beta=20"], "--workers", 1),
    ]


@settings(
    max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(case=st.sampled_from(_count_options()), value=st.integers(max_value=0))
def test_counts_below_their_minimum_are_refused(capsys, case, value):
    prefix, option, minimum = case
    value = min(value, minimum - 1)
    code, _, err = run(capsys, [*prefix, option, str(value)])
    assert_one_line_usage_error(code, err, [option, f"[{minimum}, "])


@settings(
    max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(
    option=st.sampled_from(["--beta", "--alpha", "--gamma", "--nu", "--tau", "--dt", "--duration"]),
    text=st.one_of(
        st.sampled_from(["nan", "inf", "-inf", "abc", "1e", "--", "0x1g"]),
        st.text(alphabet="abcxyz!@#", min_size=1, max_size=6),
    ),
)
def test_non_numbers_are_refused(capsys, option, text):
    argv = ["lyapunov", "--beta", "20", option, text]
    code, _, err = run(capsys, argv)
    assert_one_line_usage_error(code, err, [option.lstrip("-")])


def test_every_help_works_and_shows_defaults(capsys):
    parser = build_parser()
    sub = next(a for a in parser._actions if a.dest == "command")
    assert main(["--help"]) == 0
    assert main(["--version"]) == 0
    capsys.readouterr()
    for name in sub.choices:
        assert main([name, "--help"]) == 0, name
        out = capsys.readouterr().out
        assert "usage: cip-validate " + name in out
        assert "%" not in out.replace("95 %", ""), out  # no unformatted % left
    out_sim = (main(["simulate", "--help"]), capsys.readouterr().out)[1]
    assert "(default: 0.001)" in out_sim and "time step (s)" in out_sim


def _every_parser():
    """(command words, parser) for every command and subcommand of the CLI."""
    import argparse

    todo = [([], build_parser(full=True))]
    while todo:
        words, parser = todo.pop()
        yield words, parser
        for a in parser._actions:
            if isinstance(a, argparse._SubParsersAction):
                todo += [([*words, name], sp) for name, sp in a.choices.items()]


def test_every_command_has_a_description_and_every_option_a_help(capsys):
    import argparse

    for words, parser in _every_parser():
        if words:
            assert parser.description, words
        for a in parser._actions:
            if isinstance(a, argparse._HelpAction | argparse._SubParsersAction):
                continue
            assert a.help, (words, a.option_strings or a.dest)
        if words:
            assert main([*words, "--help"]) == 0
            out = capsys.readouterr().out
            assert "(default: None)" not in out and "(default: False)" not in out, words
            flat = " ".join(out.split())
            assert not re.search(r"\(default: [^()]*\) \(default: ", flat), words  # said twice
            assert "(default: (" not in out, words  # a tuple default shown as Python


def test_every_profile_is_named_in_the_run_help(capsys):
    from validation.profiles import PROFILES

    assert main(["run", "--help"]) == 0
    out = " ".join(capsys.readouterr().out.split())
    for name in PROFILES:
        assert f"{name} (" in out, name


def test_negative_numbers_are_values_where_valid():
    a = build_parser(full=True).parse_args(
        ["critical-gain", "--beta-range", "19", "21", "--target", "-1e9"]
    )
    assert a.target == -1e9
    a = build_parser(full=True).parse_args(
        ["simulate", "--beta", "20", "--amplitude", "-2.5E-3", "--out", "r.npz"]
    )
    assert a.amplitude == -2.5e-3


SINGLE_OPTIONS = [("--out", "{d}/r.npz"), ("--beta", "20"), ("--duration", "1"),
                  ("--realizations", "2"), ("--seed", "3"), ("--model", "single"),
                  ("--engine", "reduced"), ("--amplitude", "-0.01"), ("--json", None)]  # fmt: skip


@settings(
    max_examples=30, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(
    picks=st.lists(st.sampled_from(SINGLE_OPTIONS), min_size=1, max_size=5, unique=True),
    repeated=st.integers(min_value=0, max_value=4),
    where=st.integers(min_value=0, max_value=5),
)
def test_any_single_option_given_twice_is_refused_before_work(
    capsys, places, picks, repeated, where
):
    option, value = picks[repeated % len(picks)]
    argv = ["simulate"]
    for o, v in picks:
        argv += [o] + ([v.format(**places)] if v else [])
    if "--beta" not in argv:
        argv += ["--beta", "20"]
    extra = [option] + ([value.format(**places)] if value else [])
    pos = 1 + 2 * min(where, (len(argv) - 1) // 2)  # between two options
    argv = argv[:pos] + extra + argv[pos:]
    code, out, err = run(capsys, argv)
    assert_one_line_usage_error(code, err, [option, "given twice"])
    assert out == ""
    assert not list(Path(places["d"]).iterdir())  # nothing written


GRID_KEYS = ["beta", "gamma", "nu", "tau", "amplitude"]
VALUES = {"beta": [20, 21, 22], "gamma": [1.0, 1.5], "nu": [0.5, 0.6], "tau": [0.1, 0.11],
          "amplitude": [0.001, -0.002]}  # fmt: skip


@settings(max_examples=60, deadline=None)
@given(
    grids=st.lists(st.sampled_from(GRID_KEYS), min_size=1, max_size=3),
    sets=st.lists(st.sampled_from(GRID_KEYS), max_size=3),
    dup_value=st.booleans(),
)
def test_grid_and_set_combinations_are_refused_exactly_when_they_contradict(grids, sets, dup_value):
    """--grid/--set: refused iff a name repeats, is both swept and fixed, or a value repeats."""
    import argparse

    from cipcore.params import ParameterError
    from validation.cli.commands.sweeping import study_from_args

    def values(k: str, dup: bool) -> str:
        v = VALUES[k] + ([VALUES[k][0]] if dup else [])
        return ",".join(map(str, v))

    a = argparse.Namespace(
        study=None, model="single", engine="reduced", realizations=2, duration=1.0, seed=0,
        metrics=("rms",), grid=[f"{k}={values(k, dup_value and i == 0)}" for i, k in
                             enumerate(grids)],
        set=[f"{k}={VALUES[k][0]}" for k in sets], compare=None, target_lambda1=None,
    )  # fmt: skip
    bad = (len(set(grids)) < len(grids) or len(set(sets)) < len(sets)
           or bool(set(grids) & set(sets)) or dup_value)  # fmt: skip
    if bad:
        with pytest.raises(ParameterError) as info:
            study_from_args(a)
        msg = str(info.value)
        assert "\n" not in msg and ("--grid" in msg or "--set" in msg), msg
    else:
        study = study_from_args(a)
        assert set(study.grid) == set(grids) and set(study.fixed) == set(sets)


def test_the_docs_table_of_option_domains_is_the_declared_one():
    """docs/commands.md shows every option's domain as declared (regenerate it with
    ``validation.cli.main.domains_table()``).  The table is made in a fresh interpreter,
    as a reader's would be: an engine another test registered at run time in this process
    (``--engine-cmd``'s ``command``) is not a registered choice."""
    import subprocess
    import sys

    code = "from validation.cli.main import domains_table; print(domains_table())"
    fresh = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                           check=True, timeout=120).stdout  # fmt: skip
    text = (Path(__file__).parents[1] / "docs" / "commands.md").read_text()
    start = text.index("<!-- domains:")
    table = text[text.index("\n", start) + 1 : text.index("<!-- /domains -->")].strip()
    assert table == fresh.strip()


def test_every_option_with_a_value_has_a_declared_domain():
    """No option of cipval's own commands takes a value without a declared domain
    (the experiment's options and --grid/--set, parsed by their commands, aside)."""
    import argparse

    from validation.cli.domains import domain_of

    missing = []
    for words, parser in _every_parser():
        if words[:1] == ["experiment"]:
            continue
        for a in parser._actions:
            plain = isinstance(a, argparse._HelpAction | argparse._SubParsersAction)
            if plain or a.nargs == 0 or a.dest in ("grid", "set", "faults"):
                continue
            if domain_of(a) is None:
                missing.append((" ".join(words), a.option_strings or a.dest))
    assert not missing, missing
