"""The beta* study (issue 45): its variants of lambda1 and the study script, at tiny sizes."""

from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np
import pytest

from cipcore.scenario import Scenario
from reduced import BalanceParams
from reduced.beta_star import (
    Discretisation,
    RunPlan,
    bootstrap_indices,
    fit_beta_star,
    run_records,
)
from reduced.lyapunov import critical_gain, lyapunov_gains

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))

BASE = BalanceParams(beta=20.0)


@pytest.mark.parametrize("model", ["single", "coupled"])
@pytest.mark.parametrize(
    "setting",
    [Discretisation(), Discretisation(1e-3, hold=1e-3), Discretisation(scheme="explicit")],
)
def test_default_and_hold_dt_equal_todays_lambda1_to_the_bit(model, setting):
    betas = [19.5, 20.5]
    plan = RunPlan((10.0, 30.0), n_realizations=3, seed=5, base_dt=1e-3, transient=3.0)
    rec = run_records(model, BASE, betas, [setting], plan)[0]
    ref = lyapunov_gains(
        Scenario(model, BASE, 30.0, 3, 5),
        [BASE.with_(beta=b) for b in betas],
        transient=3.0,
        stepper=setting.scheme,
    )
    lam = rec.lambdas("delay-state", "transient", 30000)
    for g in range(2):
        assert np.array_equal(lam[g], ref[g].per_realization)


def test_beta_star_equals_critical_gain_at_todays_setting():
    plan = RunPlan((60.0,), n_realizations=4, seed=2, base_dt=1e-3, transient=6.0)
    betas = np.linspace(16.0, 26.0, 4)
    rec = run_records("single", BASE, betas, [Discretisation()], plan)[0]
    idx = bootstrap_indices(2, 4, 200)
    point, boots = fit_beta_star(betas, rec.lambdas("delay-state", "transient", 60000), 5e-4, idx)
    scn = Scenario("single", BASE, 60.0, 4, 2)
    ref = critical_gain(scn, (16.0, 26.0), target=5e-4, n_gains=4, n_bootstrap=200)
    assert point == ref.beta_star
    assert np.std(boots[np.isfinite(boots)], ddof=1) == ref.std


@pytest.mark.parametrize("scheme", ["semi-implicit", "explicit", "heun"])
def test_every_norm_measures_the_known_growth_rate_without_noise(scheme):
    """nu = 0, beta = 0: e'' + gamma e' = alpha e grows at (-gamma + sqrt(gamma^2 +
    4 alpha)) / 2 = 0.437 1/s; the four norms and both origins agree on it."""
    p = BalanceParams(beta=0.0, nu=0.0)
    exact = (-p.gamma + math.sqrt(p.gamma**2 + 4 * p.alpha)) / 2
    plan = RunPlan((200.0,), n_realizations=2, seed=1, base_dt=1e-3, transient=20.0)
    for init in ("tangent", "unit-error"):
        rec = run_records("coupled", p, [0.0], [Discretisation(scheme=scheme, init=init)], plan)[0]
        for norm in ("delay-state", "state", "positions", "balancer-1"):
            for origin in ("transient", "zero"):
                lam = rec.lambdas(norm, origin, 200000)
                tol = 2e-3 if origin == "transient" else 0.03
                assert np.all(np.abs(lam / exact - 1) < tol), (init, norm, origin, lam)


def test_held_noise_and_coarse_steps_read_one_wiener_path():
    """dt 2 ms on a 1 ms grid sums two base draws per step: lambda1 moves little from
    dt 1 ms on the same path, and much more on an independent path."""
    plan = RunPlan((100.0,), n_realizations=4, seed=3, base_dt=1e-3, transient=10.0)
    a, b, h = run_records(
        "single",
        BASE,
        [20.3],
        [Discretisation(), Discretisation(2e-3), Discretisation(1e-3, 2e-3)],
        plan,
    )
    la = a.lambdas("delay-state", "transient", 100000)[0]
    lb = b.lambdas("delay-state", "transient", 50000)[0]
    lh = h.lambdas("delay-state", "transient", 100000)[0]
    other = run_records(
        "single", BASE, [20.3], [Discretisation()], RunPlan((100.0,), 4, seed=4, base_dt=1e-3)
    )[0]
    lo = other.lambdas("delay-state", "transient", 100000)[0]
    assert np.abs(la - lb).mean() < 0.5 * np.abs(la - lo).mean()
    assert np.abs(la - lh).mean() < 0.5 * np.abs(la - lo).mean()


def test_beta_star_falls_as_the_target_rises():
    plan = RunPlan((100.0,), n_realizations=4, seed=1, base_dt=1e-3, transient=10.0)
    betas = np.linspace(17.0, 24.0, 6)
    rec = run_records("single", BASE, betas, [Discretisation()], plan)[0]
    lam = rec.lambdas("delay-state", "transient", 100000)
    idx = bootstrap_indices(1, 4, 100)
    stars = [fit_beta_star(betas, lam, t, idx)[0] for t in (-0.02, 0.0, 0.02)]
    assert np.all(np.isfinite(stars)) and stars[0] > stars[1] > stars[2]


def test_study_script_runs_small_and_refuses_bad_sizes(tmp_path, capsys):
    import beta_star_study

    out = tmp_path / "study.json"
    code = beta_star_study.main(
        [
            "--realizations",
            "2",
            "--duration",
            "20",
            "--long-realizations",
            "2",
            "--long-duration",
            "40",
            "--gains",
            "4",
            "--bootstrap",
            "100",
            "--json",
            str(out),
        ]
    )
    assert code == 0
    text = capsys.readouterr().out
    assert "| discretisation | dt 0.1 ms |" in text and "run time" in text
    assert out.stat().st_size > 0
    with pytest.raises(SystemExit) as exc:
        beta_star_study.main(["--duration", "30"])
    assert exc.value.code == 2
    assert "--duration must be a multiple of 20 s" in capsys.readouterr().err


def test_beta_star_rises_with_alpha_and_falls_with_the_noise():
    """benchmarks/beta_star_parameters.py's derivative: beta* rises with the instability
    alpha (about 0.9 per 1/s^2 at the paper's parameters) and falls with the noise
    strength nu (the random gain stabilises here), on common random numbers."""
    import argparse

    import beta_star_parameters as bsp

    a = argparse.Namespace(duration=100.0, realizations=4, seed=1, threads=1)
    betas = np.linspace(17.0, 24.0, 6)
    idx = bootstrap_indices(1, 4, 100)
    base = BalanceParams(beta=20.0)
    d_alpha, ci_alpha = bsp.sensitivity("single", base, betas, "alpha", 0.1, a, idx)
    d_nu, ci_nu = bsp.sensitivity("single", base, betas, "nu", 0.01, a, idx)
    assert 0.5 < d_alpha < 1.3 and ci_alpha[0] <= d_alpha <= ci_alpha[1]
    assert d_nu < 0 and ci_nu[1] < 0


def test_duration_benchmark_finds_the_limit_and_each_profiles_estimate(tmp_path, capsys):
    """benchmarks/beta_star_duration.py at a small size: beta* at every checkpoint, the
    fit b_inf + c / (t - t0), K per gain, the smoke profile's runs, and its JSON."""
    import json

    import beta_star_duration as bsd

    out = tmp_path / "d.json"
    assert bsd.main(["--models", "single", "--realizations", "32", "--duration", "400",
                     "--checkpoints", "100,200", "--bootstrap", "50", "--long-transient", "0",
                     "--json", str(out)]) == 0  # fmt: skip
    r = json.loads(out.read_text())["results"][0]
    assert r["times"] == [100.0, 200.0, 400.0] and len(r["beta_star"]) == 3
    assert 19.8 < r["b_inf"] < 20.8 and r["b_inf_ci"][0] <= r["b_inf_ci"][1]
    assert len(r["K"]) == len(r["betas"]) and r["dlambda_dbeta"] < 0  # lambda1 falls with beta
    smoke = r["profiles"]["smoke"]
    assert smoke["n"] == 8 and smoke["groups"] <= 4 and "bias" in smoke
    assert "b_inf" in capsys.readouterr().out
    with pytest.raises(SystemExit):
        bsd.main(["--realizations", "12"])  # not a multiple of 8, 16, 32


def test_seeds_benchmark_counts_failures_and_runs_without_a_crossing():
    """benchmarks/beta_star_seeds.py's summary: a run whose fit did not cross the target
    (no value) is a failure, and the statistics use the runs that have one."""
    import beta_star_seeds as bss

    ok = {"value": 20.4, "se": 0.1, "paper": 20.306, "tolerance": 0.5, "status": "pass"}
    rows = [{"single": ok}, {"single": {**ok, "value": 20.2}},
            {"single": {"paper": 20.306, "status": "fail"}}]  # fmt: skip
    s = bss.summary(rows)["single"]
    assert s["runs"] == 3 and s["fails"] == 1 and s["uncrossed"] == 1
    assert s["offset"] == pytest.approx(20.3 - 20.306)
