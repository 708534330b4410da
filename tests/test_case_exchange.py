"""The file protocol end to end: case export, an engine that runs the controller itself
(the shipped example, a separate program), case check."""

from __future__ import annotations

import subprocess
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest

from validation.cli.main import main

EXAMPLE = Path(__file__).resolve().parent.parent / "examples" / "case_engine.py"


@pytest.fixture(scope="module")
def case(tmp_path_factory):
    d = tmp_path_factory.mktemp("case")
    assert main(["case", "export", "--out", str(d / "case.npz"), "--seed", "1",
                 "--realizations", "2"]) == 0  # fmt: skip
    assert main(["case", "run", "--case", str(d / "case.npz"), "--out", str(d / "own.npz")]) == 0
    return d


def test_round_trip_reproduces_the_in_process_checks_bit_for_bit(case):
    from validation.checks.agreement import instrument_checks
    from validation.exchange.case import check_case, load_case

    own = dict(np.load(case / "own.npz"))
    got = {c.name: c.values for c in check_case(load_case(case / "case.npz"), own)}
    ref = {c.name: c.values for c in instrument_checks(1, 2, threads=1)}
    assert set(got) == {"twin.trajectory.single", "twin.trajectory.coupled", "twin.rod.coupled",
                        "delay.single", "delay.coupled"}  # fmt: skip
    for name, values in got.items():
        for key, v in values.items():
            assert v == ref[name][key], (name, key, v, ref[name][key])  # bit for bit


def test_example_engine_running_the_controller_passes_and_a_delay_error_fails(
    case, tmp_path, capsys
):
    ext = tmp_path / "ext.npz"
    subprocess.run([sys.executable, str(EXAMPLE), str(case / "case.npz"), str(ext)], check=True)
    own = np.load(case / "own.npz")
    with np.load(ext) as z:
        assert set(z.files) == set(own.files)
        for k in z.files:
            assert np.array_equal(z[k], own[k]), k  # the same numbers as the in-process engine
    junit = tmp_path / "c.xml"
    assert main(["case", "check", "--case", str(case / "case.npz"), "--trajectories", str(ext),
                 "--junit", str(junit)]) == 0  # fmt: skip
    assert ET.parse(junit).getroot().get("tests") == "5"
    bad = tmp_path / "bad.npz"
    subprocess.run([sys.executable, str(EXAMPLE), str(case / "case.npz"), str(bad),
                    "--delay-error"], check=True)  # fmt: skip
    capsys.readouterr()
    assert main(["case", "check", "--case", str(case / "case.npz"), "--trajectories",
                 str(bad)]) == 1  # fmt: skip
    out = capsys.readouterr().out
    assert "delay.single" in out and "measured_steps = 101" in out


def test_a_wrong_trajectories_file_is_bad_input(case, tmp_path, capsys):
    short = tmp_path / "short.npz"
    np.savez(short, **{"twin.single/balancing_error": np.zeros((2, 5, 1))})
    assert main(["case", "check", "--case", str(case / "case.npz"), "--trajectories",
                 str(short)]) == 2  # fmt: skip
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "shape (2, 5, 1)" in err


def test_the_declared_engine_must_be_a_rigid_body_engine(case, capsys):
    """``case check --engine`` takes its tolerances from the registry; the reference is refused."""
    assert main(["case", "check", "--case", str(case / "case.npz"), "--trajectories",
                 str(case / "own.npz"), "--engine", "reduced"]) == 2  # fmt: skip
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "'reduced' is not a rigid-body engine" in err
