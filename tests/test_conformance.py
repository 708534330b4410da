"""The model files' specification, the shared code's anchors and the beta* tolerances."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from cip.mjcf_params import load_model_file, read_mapping, shipped_model_path
from cipcore.models import MODEL_NAMES
from cipcore.params import BalanceParams
from validation.checks.conformance import (
    KAPPA_MAX,
    MASS_RATIO_MAX,
    bounded_margin,
    conformance_check,
    conformance_checks,
)
from validation.checks.stats import FAIL, PASS
from validation.faults.file import (
    EQUIVALENT,
    FILE_CATALOGUE,
    make_file_fault,
    write_edited,
)

#: the item of the specification each catalogued file fault must trip
EXPECTED_ITEM = {
    "file_rod_timeconst": "rod_timeconst",
    "file_rod_solimp": "rod_impedance",
    "file_mass_ratio": "mass_ratio",
    "file_kappa": "kappa",
    "file_slide_range": "joint_limits",
    "file_gravity": "gravity",
    "file_tip_damping": "tip_damping",
}


def test_shipped_files_conform():
    for c in conformance_checks(None, MODEL_NAMES):
        assert c.status == PASS, c.details
        assert all(v["ok"] and "bound" in v for v in c.values.values())


@pytest.mark.parametrize(("kind", "size"), FILE_CATALOGUE)
def test_every_file_fault_fails_conformance_naming_the_deviation(tmp_path, kind, size):
    fault = make_file_fault(kind, size)
    for model in fault.models:
        path = fault.write(model, tmp_path)
        c = conformance_check(model, str(path), BalanceParams(beta=20.0))
        assert c.status == FAIL
        assert not c.values[EXPECTED_ITEM[kind]]["ok"]
        assert EXPECTED_ITEM[kind] in c.details


@pytest.mark.parametrize("name", sorted(EQUIVALENT))
@pytest.mark.parametrize("model", MODEL_NAMES)
def test_equivalent_rewrites_read_as_the_shipped_file(tmp_path, name, model):
    path = write_edited(model, EQUIVALENT[name], tmp_path / f"{name}.xml")
    assert path.read_text() != shipped_model_path(model).read_text()
    a = read_mapping(load_model_file(shipped_model_path(model)))
    b = read_mapping(load_model_file(path))
    for f in ("pendulum_length", "cart_mass", "tip_mass", "tip_damping", "cart_damping"):
        assert getattr(b, f) == pytest.approx(getattr(a, f), rel=1e-12), f
    assert b.bob_inertia == pytest.approx(a.bob_inertia, rel=1e-6)
    assert conformance_check(model, str(path), BalanceParams(beta=20.0)).status == PASS


def test_mass_in_a_welded_child_is_read_not_refused(tmp_path):
    """The bob's mass in a child body without a joint: once refused, now read."""
    path = write_edited("single", EQUIVALENT["bob_in_welded_child"], tmp_path / "w.xml")
    mp = read_mapping(load_model_file(path))
    assert mp.tip_mass == pytest.approx(1e-3) and mp.mass_ratio <= MASS_RATIO_MAX * (1 + 1e-9)


def test_kappa_and_mass_ratio_bounds_are_the_documented_ones():
    readme = (Path(__file__).parents[1] / "README.md").read_text()
    assert (MASS_RATIO_MAX, KAPPA_MAX) == (1e-3, 1e-5)
    assert "m/M <= 1e-3" in readme and "kappa <= 1e-5" in readme


def test_bounded_margin_admits_known_terms_only_up_to_the_envelope():
    rng = np.random.default_rng(0)
    ref = rng.normal(size=32)
    full = ref + 0.5 + 1e-3 * rng.normal(size=32)  # a large known term (a soft rod, say)
    twin = full.copy()
    small = ref + 1e-3 + 1e-4 * rng.normal(size=32)  # what a conforming model produces
    m = bounded_margin(full, ref, twin - ref, small - ref)
    assert m < 0.01  # the file's 0.5 does not enter
    m2 = bounded_margin(full, ref, small - ref, twin - ref)
    assert m2 < 0.01  # the smaller of the two always decides


# ------------------------------------------------------------------ anchors
def test_anchors_pass_on_the_shared_code():
    from validation.checks.anchors import anchor_checks

    for c in anchor_checks(seed=3):
        assert c.status == PASS, (c.name, c.values)


def test_stability_boundary_matches_alpha_times_one_plus_mass_ratio():
    from validation.checks.anchors import full_boundary, reduced_boundary

    assert reduced_boundary("single") == pytest.approx(22.0, abs=1e-8)
    m = load_model_file(shipped_model_path("coupled"))
    mp = read_mapping(m)
    b = full_boundary("coupled", m, mp.pendulum_length, mp.cart_mass)
    assert b == pytest.approx(22.0 * (1 + mp.mass_ratio), rel=1e-6)


@pytest.mark.parametrize("seed", [1, 7, 11])
def test_shared_noise_scale_is_caught_by_the_gain_variance_anchor(seed):
    from validation.checks.anchors import gain_variance_check
    from validation.faults.shared import SHARED_FAULT_TYPES

    assert gain_variance_check(seed).status == PASS
    with SHARED_FAULT_TYPES["shared_noise_scale"](0.1).applied():
        assert gain_variance_check(seed).status == FAIL
    assert BalanceParams(beta=1.0).noise_scale == pytest.approx(0.6 / math.sqrt(1e-3))


def test_shared_alpha_is_caught_and_restored():
    from validation.checks.anchors import paper_constants_check
    from validation.faults.shared import SHARED_FAULT_TYPES

    with SHARED_FAULT_TYPES["shared_alpha"](0.01).applied():
        assert BalanceParams(beta=1.0).alpha == pytest.approx(22.22)
        assert paper_constants_check().status == FAIL
    assert BalanceParams(beta=1.0).alpha == 22.0
    assert paper_constants_check().status == PASS


# ------------------------------------------------------------------ beta* tolerances
def test_beta_star_tolerance_is_a_t_quantile_of_the_corrected_se_plus_precision():
    from scipy.stats import t

    from validation.paper.claims import beta_star_tolerance

    tol = beta_star_tolerance(0.1, 16, 5e-4)
    assert tol == pytest.approx(t.ppf(1 - 5e-4, 15) * 0.1 * math.sqrt(16 / 15) + 5e-4)
    assert beta_star_tolerance(0.1, 8, 0.0) > beta_star_tolerance(0.1, 16, 0.0)


def test_beta_star_tolerance_adds_the_bound_of_the_explained_offset():
    """The printed parameters' offset (docs/paper.md, "The offset and the checks") enters
    each tolerance as |offset| + 1.96 SE; the shift's is the coupled minus the single."""
    from validation.paper.claims import (
        PRINTED_PARAMETER_OFFSET,
        beta_star_tolerance,
        offset_bound,
    )

    for q, (offset, se) in PRINTED_PARAMETER_OFFSET.items():
        assert offset_bound(q) == pytest.approx(abs(offset) + 1.96 * se)
        assert beta_star_tolerance(0.1, 16, 5e-4, offset_bound(q)) == pytest.approx(
            beta_star_tolerance(0.1, 16, 5e-4) + offset_bound(q)
        )
    single, coupled, shift = (PRINTED_PARAMETER_OFFSET[q] for q in ("single", "coupled", "shift"))
    assert shift[0] == pytest.approx(coupled[0] - single[0], abs=1e-3)
    assert shift[1] == pytest.approx(math.hypot(single[1], coupled[1]), abs=1e-3)
    # the bound stays well inside what a wrong model moves: alpha 2 % off moves beta*
    # by about 0.86 x 0.44 = 0.38 (docs/paper.md, d beta*/d alpha)
    assert max(offset_bound(q) for q in PRINTED_PARAMETER_OFFSET) < 0.1


@pytest.mark.parametrize("value", ["-1", "x", "1.5"])
def test_run_seed_must_be_a_nonnegative_integer(capsys, value, tmp_path):
    from validation.cli.main import main

    code = main(["run", "--profile", "smoke", "--seed", value, "--out", str(tmp_path)])
    assert code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--seed" in err[0] and "[0, " in err[0]


def test_a_run_whose_engine_leaves_the_regime_while_the_reference_stays_is_listed():
    from validation.run import _divergence

    scan = [
        {"model": "single", "amplitude": 1e-3, "small_angle": True, "fell": True,
         "max_abs_angle": 3.1, "reference_max_abs_angle": 0.004, "engine_left_regime": True},
    ]  # fmt: skip
    (d,) = _divergence({"amplitude scan": ([], scan)})
    assert "while the reference stayed inside" in d["summary"] and "not intended" in d["summary"]


def test_beta_star_bracket_is_widened_once_when_the_target_is_not_crossed():
    """A beta* above the run's range (alpha 23 moves it by about +0.9) is found over the
    range widened by its width on each side, which the result's gains show."""
    from cipcore.params import BalanceParams
    from cipcore.scenario import Scenario
    from validation.paper.claims import BETA_RANGE, bracketed_gain

    lo, hi = BETA_RANGE["single"]
    inside = bracketed_gain(Scenario("single", BalanceParams(beta=20.0), 200.0, 4, 1), 4, 1)
    assert (inside.betas[0], inside.betas[-1]) == (lo, hi) and lo <= inside.beta_star <= hi
    res = bracketed_gain(
        Scenario("single", BalanceParams(beta=20.0, alpha=23.0), 200.0, 4, 1), 4, 1
    )
    wide = (res.betas[0], res.betas[-1])
    assert wide == pytest.approx((lo - (hi - lo), hi + (hi - lo)))
    assert hi < res.beta_star < wide[1]
