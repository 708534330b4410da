"""lambda1 of the exact twin, realisation by realisation as the engine's, and the
multifidelity lambda1 check built on it (:mod:`reduced.twin_lyapunov`,
:func:`validation.checks.agreement.lambda1_multifidelity`)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from cip.mjcf_params import read_mapping
from cipcore.noise import GainNoise, StackedNoise
from cipcore.params import BalanceParams, ParameterError
from cipcore.registry import get_engine
from cipcore.scenario import Execution, Scenario
from reduced.twin import TwinParams
from reduced.twin_lyapunov import lyapunov_twin
from validation.checks.agreement import lyapunov_checks, model_file
from validation.profiles import PROFILES


def _twin(model: str, **change) -> tuple[TwinParams, dict]:
    m = model_file(model)
    mapping = read_mapping(m)
    tw = TwinParams(**get_engine("mujoco").twin_terms(mapping))
    return replace(tw, **change), {"mj_model": m, "physical": mapping.physical()}


@pytest.mark.parametrize("model, floor", [("single", 1e-13), ("coupled", 1e-7)])
def test_twin_follows_mujoco_realisation_by_realisation(model: str, floor: float) -> None:
    """Same noise, deviation, norm and renormalisation: MuJoCo's per-realisation
    exponents equal the twin's to round-off (single) and to the soft rod's
    second-order terms (coupled, 2e-10 over 200 s, 2e-8 over 12 s), while they spread by 1e-2."""
    tw, body = _twin(model)
    scn = Scenario(model, BalanceParams(beta=21.0), 12.0, 3, 77)
    twin = lyapunov_twin(scn, tw, execution=Execution(threads=1))
    eng = get_engine("mujoco").lyapunov(model, scn.params, 12.0, 3, 77, threads=1, **body)
    assert np.abs(twin.per_realization - eng.per_realization).max() < floor
    assert np.ptp(eng.per_realization) > 1e-3
    assert twin.transient == eng.transient == 1.2


def test_another_gain_does_not_follow() -> None:
    """The pairing is the dynamics', not the noise's alone: a twin 1 % stiffer in
    gravity is off by far more than the floor above."""
    tw, body = _twin("single")
    scn = Scenario("single", BalanceParams(beta=21.0), 12.0, 3, 77)
    eng = get_engine("mujoco").lyapunov("single", scn.params, 12.0, 3, 77, threads=1, **body)
    off = lyapunov_twin(scn, replace(tw, alpha=tw.alpha * 1.01))
    assert np.abs(off.per_realization - eng.per_realization).max() > 1e-4


def test_threads_and_realisation_split_do_not_change_a_number() -> None:
    tw, _ = _twin("coupled")
    scn = Scenario("coupled", BalanceParams(beta=20.5), 6.0, 5, 3)
    one = lyapunov_twin(scn, tw, execution=Execution(threads=1)).per_realization
    two = lyapunov_twin(scn, tw, execution=Execution(threads=2)).per_realization
    head = lyapunov_twin(replace(scn, realizations=2), tw).per_realization
    np.testing.assert_array_equal(one, two)
    np.testing.assert_array_equal(one[:2], head)  # nested: the first realisations are the same


@pytest.mark.parametrize(
    "model, change, match",
    [("single", {"dt": 2e-3}, "twin.dt must equal"), ("single", {"rod": True}, "a rod needs"),
     ("coupled", {}, "epsilon must be in")],
)  # fmt: skip
def test_bad_input_is_one_line(model: str, change: dict, match: str) -> None:
    tw, _ = _twin(model, **change)
    scn = Scenario(model, BalanceParams(beta=21.0), 2.0, 2, 1)
    with pytest.raises(ParameterError, match=match):
        lyapunov_twin(scn, tw, epsilon=1e-2 if not change else 1e-7)


# ------------------------------------------------------------------ the lambda1 check
def _profile(**change):
    settings = {"lyapunov_gains": {"coupled": (20.5,)}, "lyapunov_duration": 8.0,
                "lyapunov_realizations": 4, "mf_engine_realizations": 3,
                "mf_twin_realizations": 8}  # fmt: skip
    return replace(PROFILES["smoke"], **(settings | change))


def test_lambda1_by_the_exact_twin() -> None:
    """MuJoCo on 3 realisations, its twin and the reduced model on 8: the estimate is the
    twin's mean to the pairing's floor, with the twin's 8-realisation interval."""
    (check,), data = lyapunov_checks(_profile(), 1)
    v = check.values["full"]
    assert (v["n"], v["n_twin"]) == (3, 8)
    mf = v["multifidelity"]
    assert 1 - mf["rho"] < 1e-12 and abs(mf["alpha"] - 1) < 1e-6
    assert abs(v["value"] - v["twin"]["value"]) < 1e-8
    assert check.status == "pass"
    assert "multifidelity: engine 3 x 8 s, its Euler twin and the reduced model 8 x 8 s" in (
        check.details
    )
    (row,) = data["lyapunov"]
    assert row["full"]["n_realizations"] == 3 and row["reduced"]["n_realizations"] == 8
    assert row["full"]["lambda1"] == v["value"]


def test_uncorrelated_twin_falls_back_to_plain_sampling(monkeypatch) -> None:
    """A control under other noise (rho ~ 0) widens the interval: the engine runs the
    plain allocation and the details say why."""
    import reduced.twin_lyapunov as tl

    real = tl.lyapunov_twin
    monkeypatch.setattr(
        tl, "lyapunov_twin", lambda scn, tw, **kw: real(replace(scn, seed=scn.seed + 1), tw, **kw)
    )
    (check,), data = lyapunov_checks(_profile(), 1)
    assert "multifidelity" not in check.values["full"]
    assert data["lyapunov"][0]["full"]["n_realizations"] == 4
    assert "multifidelity not used: with the engine on 3 and its twin on 8" in check.details


def test_engine_realisations_out_of_range_is_one_line() -> None:
    with pytest.raises(ParameterError, match=r"mf_engine_realizations must be 0 or in \[3, "):
        lyapunov_checks(_profile(mf_engine_realizations=4), 1)


def test_quick_profile_runs_lambda1_by_multifidelity() -> None:
    assert PROFILES["quick"].mf_engine_realizations == 3
    assert PROFILES["paper"].mf_engine_realizations == 0 == PROFILES["smoke"].mf_engine_realizations


# ------------------------------------------------------------------ several gains, one batch
def test_gains_in_one_batch_are_each_gain_alone() -> None:
    """Two gains, two seeds, one engine call (a stack of their noises, a gain per
    realisation) on two threads, so that a block holds realisations of both gains:
    every draw and every exponent is the one its gain's run alone gives, bit for bit."""
    _, body = _twin("coupled")
    runs = [(20.5, 11), (22.0, 12)]
    noise = StackedNoise([GainNoise(seed, 2, 2) for _, seed in runs])
    assert [noise.stream(r) for r in range(4)] == [(11, 0), (11, 1), (12, 0), (12, 1)]
    np.testing.assert_array_equal(
        noise.next_chunk(50),
        np.concatenate([GainNoise(seed, 2, 2).next_chunk(50) for _, seed in runs]),
    )
    noise.reset()
    engine = get_engine("mujoco")
    batch = engine.lyapunov("coupled", BalanceParams(beta=20.5), 3.0, 4, 11, threads=2,
                            noise=noise, betas=[20.5, 20.5, 22.0, 22.0], **body)  # fmt: skip
    for g, (beta, seed) in enumerate(runs):
        alone = engine.lyapunov("coupled", BalanceParams(beta=beta), 3.0, 2, seed, threads=1,
                                **body)  # fmt: skip
        part = batch.part(slice(2 * g, 2 * g + 2), beta, seed)
        np.testing.assert_array_equal(part.per_realization, alone.per_realization)
        assert part.lambda1 == alone.lambda1 and part.params["beta"] == beta
        assert part.seed == seed and "betas" not in part.params


@pytest.mark.parametrize(
    "betas, match",
    [([21.0] * 3, r"betas must give one gain per realisation \(4\), got 3"),
     ([21.0, -1.0, 21.0, 21.0], "finite gains >= 0")],
)  # fmt: skip
def test_betas_that_do_not_fit_are_one_line(betas: list, match: str) -> None:
    _, body = _twin("single")
    with pytest.raises(ParameterError, match=match):
        get_engine("mujoco").lyapunov("single", BalanceParams(beta=21.0), 1.0, 4, 1,
                                      threads=1, betas=betas, **body)  # fmt: skip


def test_a_duration_of_part_of_a_delay_pairs_too() -> None:
    """The last chunk shorter than tau is renormalised at its end by both estimators."""
    tw, body = _twin("single")
    scn = Scenario("single", BalanceParams(beta=21.0), 6.05, 2, 8)
    twin = lyapunov_twin(scn, tw, execution=Execution(threads=1))
    eng = get_engine("mujoco").lyapunov("single", scn.params, 6.05, 2, 8, threads=1, **body)
    assert np.abs(twin.per_realization - eng.per_realization).max() < 1e-13


def test_two_gains_of_a_model_each_get_their_check() -> None:
    checks, data = lyapunov_checks(_profile(lyapunov_gains={"coupled": (20.5, 21.5)}), 2)
    assert [c.name for c in checks] == ["agreement.lambda1.coupled.beta=20.5",
                                        "agreement.lambda1.coupled.beta=21.5"]  # fmt: skip
    assert all(c.status == "pass" for c in checks)
    assert all("the engine ran the 2 gains' realisations in one batch" in c.details
               for c in checks)  # fmt: skip
    seeds = [row["full"]["seed"] for row in data["lyapunov"]]
    assert seeds == [row["reduced"]["seed"] for row in data["lyapunov"]] and len(set(seeds)) == 2


def test_the_engine_over_a_shorter_duration() -> None:
    """mf_engine_duration 4 s of the 8 s: the engine and the twin's pairs over 4 s, the
    twin's and reduced model's 8 realisations over 8 s."""
    (check,), data = lyapunov_checks(_profile(mf_engine_duration=4.0), 1)
    assert check.status == "pass"
    assert "multifidelity: engine 3 x 4 s, its Euler twin and the reduced model 8 x 8 s" in (
        check.details
    )
    assert "paired with its twin over the same 4 s" in check.details
    (row,) = data["lyapunov"]
    assert row["full"]["duration"] == 4.0 and row["twin"]["duration"] == 8.0
    v = check.values["full"]
    assert abs(v["value"] - v["twin"]["value"]) < 1e-8  # the exact twin: no correction


def test_a_fault_moves_lambda1_alike_over_either_duration() -> None:
    """What lets the engine run shorter: the paired difference engine - twin of a faulty
    engine (tip damping 5 % too high) is the same over 20 s as over 80 s, to 2 % of itself
    (-0.022 1/s; over 25, 50 and 200 s, 8 realisations: -0.0218, -0.0221, -0.0220)."""
    from validation.faults.catalogue import make_fault

    tw, body = _twin("single")
    engine = get_engine("mujoco")
    backend = make_fault("tip_damping", 0.05).backend(engine.rollout())
    d = {}
    for duration in (20.0, 80.0):
        scn = Scenario("single", BalanceParams(beta=20.3), duration, 3, 5)
        eng = engine.lyapunov("single", scn.params, duration, 3, 5, threads=1, backend=backend,
                              **body)  # fmt: skip
        d[duration] = (eng.per_realization - lyapunov_twin(scn, tw).per_realization).mean()
    assert d[80.0] < -0.015
    assert abs(d[20.0] - d[80.0]) < 0.02 * abs(d[80.0])


def test_an_engine_duration_out_of_range_is_one_line() -> None:
    with pytest.raises(ParameterError, match=r"mf_engine_duration must be 0 or in \[0.112, "
                                             r"lyapunov_duration = 8\] s, got 9"):  # fmt: skip
        lyapunov_checks(_profile(mf_engine_duration=9.0), 1)


@pytest.mark.parametrize("mf", [3, 0])
def test_an_engine_gone_non_finite_fails_lambda1_and_the_run_goes_on(
    mujoco_nan_after, tmp_path, mf
) -> None:
    """An engine whose Benettin state goes non-finite (the multifidelity allocation and the
    plain one): the lambda1 check fails and says where, the stage's row keeps the
    realisations' times and the run's divergence summary names them (the stage used to
    crash with FloatingPointError and lose the rest of the run)."""
    import numpy as np

    from cip.simulate import DivergenceWarning
    from validation.run import _stage_divergence

    mujoco_nan_after(2000)  # MuJoCo's state NaN in each block's first realisation
    with pytest.warns(DivergenceWarning, match="mujoco lambda1 run: non-finite state"):
        (check,), data = lyapunov_checks(_profile(mf_engine_realizations=mf), 1)
    assert check.status == "fail" and check.values["full"]["value"] == np.inf
    assert "the engine's state went non-finite in 1 of" in check.details
    (row,) = data["lyapunov"]
    at = row["full"]["diverged_at"]
    assert at[0] == pytest.approx(2.0 + 0.1) and all(t is None for t in at[1:])
    (line,) = _stage_divergence("lambda1 agreement", (None, data))
    assert line["run"] == "coupled beta 20.5 engine" and "realisations [0] of" in line["summary"]
    if mf:  # Fig. 3 leaves the point out and says so (it raised on the interval's None)
        import matplotlib

        matplotlib.use("Agg")
        from validation.report.document import jsonable
        from validation.report.plots import fig_lle

        assert fig_lle({}, jsonable(data["lyapunov"]), {}, tmp_path / "l.png").stat().st_size
