"""The exact linear twin, the model-file mapping, the direct checks and the fault catalogue."""

from __future__ import annotations

import copy

import mujoco
import numpy as np
import pytest

from cip.mjcf_params import load_model_file, read_mapping, shipped_model_path
from cip.model import CIPParams, build, mjcf
from cip.runner import MujocoRollout, RigidBody
from cip.simulate import simulate_full
from cipcore.params import BalanceParams, ParameterError
from cipcore.registry import get_engine
from cipcore.scenario import Recording, Scenario
from reduced.twin import TwinParams, simulate_twin
from validation.checks.agreement import instrument_checks, measured_delay
from validation.faults.catalogue import CATALOGUE, make_fault

BETA = {"single": 20.306, "coupled": 21.032}
TWIN_TOLERANCE = get_engine("mujoco").twin_tolerance_for("coupled")


def _pair(model, amplitude, twin_params=None, duration=2.0):
    m = load_model_file(shipped_model_path(model))
    mp = read_mapping(m)
    p = BalanceParams(beta=BETA[model])
    tw = twin_params or TwinParams(**mp.twin_terms())
    scn = Scenario(model, p, duration, 2, 3, amplitude=amplitude)
    rec = Recording(fields=("balancing_error",))
    full = simulate_full(scn, body=RigidBody(mp.physical(), mj_model=m), recording=rec)
    twin = simulate_twin(scn, tw, recording=rec)
    ef, et = full["balancing_error"], twin["balancing_error"]
    return np.linalg.norm(ef - et) / np.linalg.norm(et)


@pytest.mark.parametrize("model", ["single", "coupled"])
def test_twin_matches_mujoco_to_its_floor(model):
    """At 1e-6 m the full model and its twin agree far below 1e-6 (floor ~2e-11)."""
    assert _pair(model, 1e-6) < TWIN_TOLERANCE


def test_twin_floor_is_second_order_in_the_angle():
    """The residual scales as the amplitude squared: the terms the twin leaves out."""
    r5, r4 = _pair("single", 1e-5), _pair("single", 1e-4)
    assert r4 / r5 == pytest.approx(100, rel=0.05)


@pytest.mark.parametrize(
    "term", [{"mass_ratio": 1.1e-3}, {"alpha": 22.0 * 1.0001}, {"gamma_cart": 50.05}]
)
def test_twin_terms_matter(term):
    """Each known term the twin carries is visible far above the floor."""
    mp = read_mapping(load_model_file(shipped_model_path("single")))
    tw = TwinParams(**{**mp.twin_terms(), **term})
    assert _pair("single", 1e-6, tw) > 1e3 * TWIN_TOLERANCE


def test_mapping_reads_the_generator_parameters():
    p = CIPParams(pendulum_length=0.5, bob_mass=2e-3, solref=(0.004, 0.9), timestep=5e-4)
    mp = read_mapping(build("coupled", p))
    assert mp.pendulum_length == pytest.approx(0.5, rel=1e-14)
    assert mp.mass_ratio == pytest.approx(2e-3, rel=1e-14)
    assert mp.timestep == 5e-4 and mp.integrator == "Euler"
    rod = mp.rod_constants()
    k = 0.99 / (0.99**2 * 0.004**2 * 0.9**2)
    assert rod["stiffness"] == pytest.approx(k, rel=1e-14)
    # MuJoCo's own constraint constants at the initial state
    m = build("coupled", p)
    d = mujoco.MjData(m)
    mujoco.mj_forward(m, d)
    assert d.efc_KBIP[0, 0] * d.efc_KBIP[0, 2] == pytest.approx(rod["stiffness"], rel=1e-12)
    assert d.efc_KBIP[0, 1] == pytest.approx(rod["damping"], rel=1e-12)
    assert d.efc_R[0] == pytest.approx(rod["regulariser"], rel=1e-12)


def test_mapping_error_names_what_is_missing(tmp_path):
    text = mjcf("single").replace('name="cart_damping_1"', 'name="damper"')
    f = tmp_path / "bad.xml"
    f.write_text(text)
    with pytest.raises(ParameterError, match="no actuator 'cart_damping_1'"):
        read_mapping(load_model_file(f))
    f.write_text(mjcf("single").replace('name="tip_1"', 'name="bob_site"'))
    with pytest.raises(ParameterError, match=r"does not compile: .*'tip_1' not found"):
        load_model_file(f)
    with pytest.raises(ParameterError, match="no such file"):
        load_model_file(tmp_path / "absent.xml")


def test_delay_measured_from_the_response_is_tau_over_the_model_timestep():
    """The check reads tau and the model's timestep, never the runner's d."""
    m = load_model_file(shipped_model_path("single"))
    mp = read_mapping(m)
    p = BalanceParams(beta=BETA["single"], tau=0.02)
    assert measured_delay("single", p, mp.physical(), m) == round(0.02 / m.opt.timestep)
    late = make_fault("delay_late", 1)
    assert measured_delay("single", p, mp.physical(), m, late.backend(MujocoRollout)) == 21


def test_unmodified_model_passes_every_direct_check():
    checks = instrument_checks(1, 2, threads=1)
    assert [c.name for c in checks if c.status != "pass"] == []


def test_fault_backend_leaves_the_declared_model_alone():
    m = load_model_file(shipped_model_path("coupled"))
    before = copy.deepcopy(m.opt.gravity)
    backend = make_fault("gravity", 0.005).backend(MujocoRollout)
    b = backend(m, 1, 1)
    assert b.faulty_model.opt.gravity[2] == pytest.approx(before[2] * 1.005)
    np.testing.assert_array_equal(m.opt.gravity, before)


def test_selftest_flags_every_catalogued_fault(selftest_run):
    """CI's fast subset: the whole catalogue at its listed sizes, 2 realisations (the
    session's `cip-validate selftest` run: run_selftest(seed=1, n_realizations=2))."""
    code, doc, _, args, (clean, rows) = selftest_run
    assert args == (1, 2, None, "mujoco", None) and code == 0 and doc["pass"] is True
    from validation.faults.file import FILE_CATALOGUE
    from validation.faults.shared import SHARED_CATALOGUE

    assert clean == []
    assert len([r for r in rows if "path" not in r]) == len(CATALOGUE)
    assert len(rows) == len(CATALOGUE) + len(FILE_CATALOGUE) + len(SHARED_CATALOGUE)
    missed = [r["fault"] for r in rows if not r["flagged"]]
    assert missed == []


def test_paired_rules_use_the_paired_uncertainty():
    from validation.checks.stats import needed_realizations, paired_equivalence, paired_shift

    rng = np.random.default_rng(0)
    base = rng.normal(0, 1, 16)  # the spread across realisations: large
    known = 0.01 + 1e-3 * rng.normal(size=16)  # what the known terms predict, paired
    ok = base + known + 1e-4 * rng.normal(size=16)
    assert paired_equivalence(ok, base, expected=known)[0] == "pass"
    # a shift 20x the paired resolution but 50x below the spread across realisations fails
    assert paired_equivalence(ok + 0.02, base, expected=known)[0] == "fail"
    st, v = paired_equivalence(ok + 0.0005, base, expected=known)
    assert st == "inconclusive" and v["needed_realizations"] > 16
    assert needed_realizations(np.full(4, 2.0), 1.0) is None
    assert paired_shift(base + 1e-12, base, floor=1e-9)[0] == "pass"
    assert paired_shift(base + 1e-6, base, floor=1e-9)[0] == "fail"


def test_baseline_mode_follows_what_changes_numbers_not_the_kernel_string():
    from validation.regression.baseline import BaselineMismatch, choose_mode

    fp = {"machine": "x86_64", "cpu_flags": ["avx2", "fma"], "numpy_build": {"blas": "b"},
          "blas_kernels": ["openblas 0.3.31 SkylakeX"],
          "model_digests": {"single": "1", "coupled": "2"}}  # fmt: skip
    a = {"versions": {"mujoco": "4.0.0"}, "platform": "Linux-6.1-x86_64", "fingerprint": fp}
    other_kernel = {**a, "platform": "Linux-6.18.44-fc-v782-x86_64"}
    assert choose_mode(a, other_kernel)[0] == "exact"
    no_fma = {**a, "fingerprint": {**fp, "cpu_flags": ["avx2"]}}
    mode, why = choose_mode(a, no_fma)
    assert mode == "roundoff" and "+fma" in why
    # the same flags, OpenBLAS on other kernels (it chooses them by CPU family and model)
    other_blas = {**a, "fingerprint": {**fp, "blas_kernels": ["openblas 0.3.31 Haswell"]}}
    mode, why = choose_mode(a, other_blas)
    assert mode == "roundoff" and "blas_kernels" in why and "Haswell" in why
    unrecorded = {k: v for k, v in fp.items() if k != "blas_kernels"}
    mode, why = choose_mode(a, {**a, "fingerprint": unrecorded})
    assert mode == "roundoff" and "does not record its blas kernels" in why
    old = {"versions": {"mujoco": "4.0.0"}, "platform": "y"}  # no fingerprint recorded
    assert choose_mode(a, old)[0] == "roundoff"
    b = {"versions": {"mujoco": "3.5.0"}, "platform": "x", "fingerprint": fp}
    mode, why = choose_mode(a, b)
    assert mode == "statistical" and "mujoco 3.5.0 -> 4.0.0" in why
    other_model = {**a, "fingerprint": {**fp, "model_digests": {"single": "1", "coupled": "3"}}}
    with pytest.raises(BaselineMismatch, match="model files differ \\(coupled\\)"):
        choose_mode(a, other_model)
    mode, why = choose_mode(a, other_model, "statistical")
    assert mode == "statistical" and "model files differ" in why


def test_roundoff_mode_compares_every_number_to_its_stated_tolerance():
    from validation.regression.baseline import ROUNDOFF_RTOL, all_numbers, compare_with_baseline

    base = {"checks": [{"name": "c", "values": {"x": 1.0, "d": 3e-15, "measured_steps": 100}}]}
    near = {"checks": [{"name": "c", "values": {"x": 1.0 + ROUNDOFF_RTOL / 2, "d": -2e-15,
                                                 "measured_steps": 100}}]}  # fmt: skip
    far = {"checks": [{"name": "c", "values": {"x": 1.0 + 3 * ROUNDOFF_RTOL, "d": 3e-15,
                                                "measured_steps": 101}}]}  # fmt: skip
    ok = compare_with_baseline(near, base, "roundoff")
    assert len(ok) == len(all_numbers(base)) == 3 and all(c.status == "pass" for c in ok)
    bad = [c.name for c in compare_with_baseline(far, base, "roundoff") if c.status == "fail"]
    assert bad == ["regression.c.measured_steps", "regression.c.x"]
    assert [c.status for c in compare_with_baseline(near, base, "exact")].count("fail") == 2


def test_a_difference_beside_its_operands_is_held_to_their_round_off():
    """anchor.stability_boundary-like values: 22.022 - 22.0 moved by 2.3e-11 when both
    operands moved by round-off (measured between OpenBLAS's Haswell and SkylakeX
    kernels); the same move of a difference recorded without its operands, or a move
    far beyond the operands' round-off, fails."""
    from validation.regression.baseline import (
        ROUNDOFF_RTOL,
        compare_with_baseline,
        difference_scales,
    )

    def run(full, red, with_operands=True):
        v = {"difference": full - red, "tolerance": 0.05}
        if with_operands:
            v |= {"full_linearised": full, "reduced_characteristic_roots": red}
        return {"checks": [{"name": "anchor", "values": v}]}

    base = run(22.02200006189668, 22.0)
    assert difference_scales(base) == {"anchor.difference": 22.02200006189668}
    for full in (22.022000061919655, 22.02200006189668 * (1 + 5e-12)):
        # +1.04e-12 relative (measured; the difference +1.04e-9) and +5e-12 (the difference
        # +5e-9 relative: beyond ROUNDOFF_RTOL of its own size)
        moved = run(full, 22.0)
        assert all(c.status == "pass" for c in compare_with_baseline(moved, base, "roundoff"))
    alone = [c.status for c in compare_with_baseline(
        run(22.022000061919655 + 3e-11, 22.0, False), run(22.02200006189668, 22.0, False),
        "roundoff")]  # fmt: skip
    assert alone == ["fail", "pass"]  # the difference, then the tolerance
    far = run(22.02200006189668 * (1 + 3 * ROUNDOFF_RTOL), 22.0)
    bad = sorted(c.name for c in compare_with_baseline(far, base, "roundoff")
                 if c.status == "fail")  # fmt: skip
    assert bad == ["regression.anchor.difference", "regression.anchor.full_linearised"]


def test_selftest_cli(selftest_run, monkeypatch, capsys):
    """`selftest --faults gravity` in text: the real run_selftest runs the unmodified model
    and the gravity fault only; their verdicts (which checks fail) are replayed from the
    session's whole-catalogue run (same seed, realisations and engine)."""
    from validation.cli.main import main
    from validation.faults import selftest, selftest_paths

    _, _, _, args, (clean, rows) = selftest_run
    by = {r["fault"]: r["by"] for r in rows if "path" not in r}
    ran = []

    def replayed(fault, seed, n_realizations, engine="mujoco", integrator=None):
        assert (seed, n_realizations, engine, integrator) == (*args[:2], *args[3:])
        ran.append(None if fault is None else fault.kind)
        return clean if fault is None else by[fault.kind]

    monkeypatch.setattr(selftest, "flagged_by", replayed)
    monkeypatch.setattr(selftest_paths, "clean_failures", lambda seed, n: [])  # in `clean`
    assert main(["selftest", "--faults", "gravity"]) == 0
    out = capsys.readouterr().out
    assert ran == [None, "gravity"]
    assert "gravity" in out and "unmodified model: pass" in out
    assert "selftest of mujoco passes: 1 of 1 applicable faults flagged" in out
    assert main(["selftest", "--faults", "nonsense"]) == 2
    err = capsys.readouterr().err
    assert "--faults" in err and "fault must be one of" in err and "gravity" in err


def test_run_refuses_a_bad_model_file_before_running(tmp_path, capsys):
    from validation.cli.main import main

    f = tmp_path / "dt.xml"
    f.write_text(mjcf("single", CIPParams(timestep=2e-3)))
    assert main(["run", "--mjcf", str(f), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "timestep 0.002" in err
    assert not (tmp_path / "o").exists()
    assert main(["run", "--mjcf", str(tmp_path / "absent.xml")]) == 2
    assert "no such file" in capsys.readouterr().err
