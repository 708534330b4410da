"""Work and memory bounds of ``cip-validate selftest`` (issue 42).

Before any work the selftest estimates its work in realisation-steps from the runs it
will make (:func:`validation.faults.selftest.selftest_work`) and refuses, in one line
naming ``--realizations`` and the estimate, beyond :data:`validation.cli.args.MAX_WORK`
unless ``--force``; a count whose recording exceeds the memory cap is refused in one
line naming ``--realizations`` too.  Every refusal here happens before any simulation
(each command returns in well under a second); one test runs the cheapest selftest
(``--faults gravity --realizations 1``, a few seconds) to check that the estimate counts
the simulations that actually run.
"""

from __future__ import annotations

import re

import pytest

from cipcore.params import ParameterError
from validation.cli.args import MAX_WORK, check_work
from validation.cli.main import build_parser, main
from validation.faults.selftest import (
    SIMULATIONS_PER_MODEL,
    check_recording,
    fixed_steps,
    model_runs,
    selftest_work,
)

#: the message of check_work with a fixed term: (work, realisations, runs, fixed)
ESTIMATE = re.compile(
    r"^cip-validate: error: --realizations: estimated work (\S+) realisation-steps "
    r"\((\d+) realisations x (\d+) run\(s\) x 10 s / dt 0\.001 s \+ (\S+) fixed\) "
    r"exceeds 2e\+10; lower it or pass --force$"
)


def run_cli(argv: list[str], capsys) -> tuple[int, list[str]]:
    """(exit status, stderr lines) of ``cip-validate argv`` run in this process."""
    code = main(argv)
    return code, capsys.readouterr().err.splitlines()


def test_huge_realizations_refused_naming_option_and_estimate(capsys):
    code, err = run_cli(["selftest", "--realizations", "100000"], capsys)
    assert code == 2
    assert len(err) == 1, err
    m = ESTIMATE.match(err[0])
    assert m, err[0]
    work, n, runs, fixed = float(m[1]), int(m[2]), int(m[3]), float(m[4])
    plan = model_runs(None, "mujoco", power=False)
    assert n == 100000
    assert runs == SIMULATIONS_PER_MODEL * len(plan)
    assert fixed == pytest.approx(sum(fixed_steps(e, mo) for e, mo in plan), rel=1e-3)
    assert work == pytest.approx(n * runs * 10.0 / 1e-3 + fixed, rel=1e-3)
    assert work > MAX_WORK


def test_power_counts_its_bisection_runs(capsys):
    # 4000 realisations: below the bound without --power, above it with the bisections
    assert selftest_work(4000) < MAX_WORK
    code, err = run_cli(["selftest", "--realizations", "4000", "--power"], capsys)
    assert code == 2 and len(err) == 1, err
    m = ESTIMATE.match(err[0])
    assert m, err[0]
    plain, power = model_runs(None, "mujoco", False), model_runs(None, "mujoco", True)
    assert len(power) > len(plain)
    assert int(m[3]) == SIMULATIONS_PER_MODEL * len(power)


def test_fault_selection_lowers_the_estimate():
    assert selftest_work(1, ["gravity"]) < selftest_work(1)
    # the unmodified model and the equivalent rewrites run whatever --faults selects
    assert len(model_runs(["gravity"], "mujoco", False)) == 2 + 3 * 2 + 2


def test_force_passes_the_work_bound_but_not_the_memory_cap(capsys):
    code, err = run_cli(["selftest", "--realizations", "100000", "--force"], capsys)
    assert code == 2 and len(err) == 1, err
    line = err[0]
    assert line.startswith("cip-validate: error: --realizations: ")
    assert "recording" in line and "GiB" in line and "estimated work" not in line
    most = int(re.search(r"at most (\d+) realisations$", line)[1])
    check_recording(most, ["single", "coupled"])  # the count offered is accepted
    with pytest.raises(ParameterError, match=r"^--realizations: "):
        check_recording(most + 1, ["single", "coupled"])


def test_memory_cap_named_below_the_work_bound(capsys):
    # 10000 realisations: ~1.1e10 realisation-steps (accepted) but 3 GiB per recording
    runs = SIMULATIONS_PER_MODEL * len(model_runs(None, "mujoco", False))
    assert 10000 * runs * 10.0 / 1e-3 < MAX_WORK
    code, err = run_cli(["selftest", "--realizations", "10000"], capsys)
    assert code == 2 and len(err) == 1, err
    assert err[0].startswith("cip-validate: error: --realizations: the coupled model's recording")
    assert "max_bytes" in err[0] and "raise decimate" not in err[0]


def test_check_work_message_without_fixed_is_unchanged():
    with pytest.raises(ParameterError) as exc:
        check_work("--duration", 10**6, 100.0, 1e-3)
    text = str(exc.value)
    assert text == (
        "--duration: estimated work 1e+11 realisation-steps (1000000 realisations x 1 run(s) "
        "x 100 s / dt 0.001 s) exceeds 2e+10; lower it or pass --force"
    )
    assert check_work("--duration", 10**6, 100.0, 1e-3, force=True) == pytest.approx(1e11)
    assert check_work("--duration", 1, 1.0, 1e-3, runs=2, fixed=5.0) == pytest.approx(2005.0)


def test_small_selftest_parses_with_and_without_force():
    parser = build_parser("selftest")
    a = parser.parse_args(["selftest", "--faults", "gravity", "--realizations", "1"])
    assert (a.realizations, a.force, a.power) == (1, False, False)
    a = parser.parse_args(["selftest", "--realizations", "100000", "--force", "--power"])
    assert (a.realizations, a.force, a.power) == (100000, True, True)
    assert selftest_work(2) < MAX_WORK


def test_force_help_states_the_bound(capsys):
    with pytest.raises(SystemExit):
        build_parser("selftest").parse_args(["selftest", "--help"])
    out = " ".join(capsys.readouterr().out.split())
    assert "--force" in out and "2e+10 realisation-steps" in out


def test_estimate_counts_the_simulations_that_run(monkeypatch, capsys):
    """The cheapest selftest: each model of each instrument_checks call runs the engine
    and its twin once; the estimate's model runs are the twin's calls."""
    import reduced.twin

    calls = []
    twin = reduced.twin.simulate_twin

    def counted(*args, **kwargs):
        calls.append(1)
        return twin(*args, **kwargs)

    monkeypatch.setattr(reduced.twin, "simulate_twin", counted)
    code = main(["selftest", "--faults", "gravity", "--realizations", "1"])
    assert code == 0, capsys.readouterr()
    assert len(calls) == len(model_runs(["gravity"], "mujoco", False))
