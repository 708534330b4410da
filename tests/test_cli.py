"""The command line: JSON output, exit codes, one-line errors."""

from __future__ import annotations

import json

import pytest

from validation.cli.main import main


def run(capsys, *argv):
    code = main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


def test_lyapunov_json(capsys):
    code, out, _ = run(
        capsys, "lyapunov", "--model", "coupled", "--beta", "23", "--nu", "0",
        "--duration", "50", "--realizations", "2", "--json",
    )  # fmt: skip
    assert code == 0
    d = json.loads(out)
    assert d["lambda1"] < 0 and len(d["ci95"]) == 2 and d["ci95"][0] <= d["lambda1"] <= d["ci95"][1]


def test_lyapunov_beyond_float64_is_one_line_naming_beta(capsys):
    """A gain whose tangent growth overflows float64 within one renormalisation interval
    (beta 1e300) gets one line naming beta, not a ZeroDivisionError from the kernel."""
    code, _, err = run(capsys, "lyapunov", "--duration", "0.2", "--realizations", "2",
                       "--beta", "1e300")  # fmt: skip
    assert code == 2
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "beta 1e+300" in lines[0] and "float64's range" in lines[0], err


def test_stability_json_and_plot(capsys, tmp_path):
    png = tmp_path / "region.png"
    code, out, _ = run(
        capsys, "stability", "--model", "single", "--beta", "30", "--json", "--plot", str(png),
        "--beta-grid", "0:60:7", "--tau-grid", "0.05:0.2:4",
    )  # fmt: skip
    assert code == 0
    d = json.loads(out)
    assert d["stable"] is True and d["abscissa"] < 0
    assert png.stat().st_size > 1000


def test_simulate_writes_schema(capsys, tmp_path):
    out_file = tmp_path / "run.npz"
    code, _, _ = run(
        capsys, "simulate", "--model", "coupled", "--beta", "20.3", "--duration", "0.5",
        "--realizations", "2", "--out", str(out_file),
    )  # fmt: skip
    assert code == 0
    from reduced import Trajectory

    tr = Trajectory.load_npz(out_file)
    assert tr["balancing_error"].shape == (2, 500, 2)


@pytest.mark.parametrize(
    ("argv", "name"),
    [
        (["lyapunov", "--beta", "-3"], "beta"),
        (["lyapunov", "--beta", "20", "--tau", "0.1234"], "tau"),
        (["lyapunov", "--beta", "20", "--realizations", "0"], "realizations"),
        (["lyapunov", "--beta", "nan"], "beta"),
        (["lyapunov", "--beta", "20", "--dt", "-1"], "dt"),
    ],
)
def test_bad_input_is_one_line_exit_2(capsys, argv, name):
    code, _, err = run(capsys, *argv)
    assert code == 2
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert len(lines) == 1 and name in lines[0] and "Traceback" not in err


def test_simulate_reports_divergence_and_keeps_the_data(capsys, tmp_path):
    """beta = 2 is far below the stability threshold: every realisation's balancing error
    passes |e| > L = g/alpha within 20 s; simulate says which, when and how far, and the
    saved series runs to the end."""
    out_file = tmp_path / "div.npz"
    code, out, _ = run(
        capsys, "simulate", "--beta", "2", "--duration", "20", "--realizations", "2",
        "--out", str(out_file), "--json",
    )  # fmt: skip
    assert code == 0
    d = json.loads(out)
    assert [e["realization"] for e in d["divergence"]] == [0, 1]
    for e in d["divergence"]:
        assert e["kind"] == "diverged" and 0 < e["time"] < 20 and e["extent"] > 0.446
    from reduced import Trajectory

    tr = Trajectory.load_npz(out_file)
    assert tr["balancing_error"].shape == (2, 20000, 1)
    code, out, _ = run(
        capsys, "simulate", "--beta", "20.3", "--duration", "2", "--realizations", "2",
        "--amplitude", "1e-4", "--out", str(out_file), "--json",
    )  # fmt: skip
    assert code == 0 and json.loads(out)["divergence"] == []
