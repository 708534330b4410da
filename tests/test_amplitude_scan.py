"""The amplitude scan's small-angle regime: judged by the reference over every stick, and an
engine that leaves it while the reference stays inside is told apart from one that merely
scales (``validation.checks.agreement.amplitude_scan``, ``mark_engine_left``)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from cip.model import small_angle_limit
from validation.checks.agreement import ENGINE_LEFT_TOLERANCE, amplitude_scan, mark_engine_left
from validation.profiles import PROFILES

LIMIT = small_angle_limit()


def _rows(amplitudes, reference, engine):
    return [{"amplitude": a, "reference_max_abs_angle": r, "max_abs_angle": e}
            for a, r, e in zip(amplitudes, reference, engine, strict=True)]  # fmt: skip


def test_an_engine_that_scales_with_its_linear_excess_stays_inside():
    # the engine 0.75 % above the reference at every amplitude (its rigid body against the
    # m/M -> 0 reference): at the edge of the regime it is past the limit and past 1 % of
    # the reference's angle scaled by nothing but its own linear excess
    amps = np.array([1e-5, 1e-3, 1e-2])
    ref = amps * (0.99 * LIMIT / 1e-2)
    excess = 1.0075
    rows = _rows(amps, ref, ref * excess * np.array([1.0, 1.0, 1.0045]))
    assert rows[-1]["max_abs_angle"] > max(LIMIT, 1.01 * rows[-1]["reference_max_abs_angle"])
    mark_engine_left(rows, LIMIT)
    assert [r["engine_left_regime"] for r in rows] == [False, False, False]


def test_an_engine_that_hits_a_joint_limit_left_the_regime():
    # the catalogue's cart slide range of 0.02 m: the engine falls to 0.41 rad at 0.01 m
    # while the reference stays at 0.041 rad
    rows = _rows([1e-5, 1e-2], [4.1e-5, 0.041], [4.1e-5, 0.41])
    mark_engine_left(rows, LIMIT)
    assert [r["engine_left_regime"] for r in rows] == [False, True]


def test_the_tolerance_is_measured_from_the_linear_excess():
    # the engine 0.5 % above the reference at 1e-5 m; at 1e-2 m the reference is just
    # inside the regime, and the engine is left there just past (1 + tolerance) x 1.005 x
    # the reference's angle, not just inside it
    ref = 0.995 * LIMIT
    scaled = (1.0 + ENGINE_LEFT_TOLERANCE) * 1.005 * ref
    assert scaled > LIMIT
    for factor, left in ((1.001, True), (0.999, False)):
        rows = _rows([1e-5, 1e-2], [1e-5, ref], [1.005e-5, factor * scaled])
        mark_engine_left(rows, LIMIT)
        assert rows[1]["engine_left_regime"] is left


def test_outside_the_regime_the_engine_never_left_it():
    rows = _rows([1e-5, 3e-2], [4e-5, 0.2], [4e-5, 3.0])
    mark_engine_left(rows, LIMIT)
    assert not any(r["engine_left_regime"] for r in rows)


@pytest.mark.parametrize("first", [np.inf, np.nan])
def test_an_engine_that_fell_at_the_smallest_amplitude_is_not_scaled_away(first):
    rows = _rows([1e-5, 1e-2], [4e-5, 0.05], [first, 0.3])
    mark_engine_left(rows, LIMIT)
    assert rows[1]["engine_left_regime"]


def test_the_reference_reads_every_stick_of_the_coupled_model():
    # seed 7, quick profile: at 0.01 m the coupled model's second stick goes past the
    # regime's limit while the first stays inside (0.0751 rad); read on the first stick
    # only, the reference called the run inside and the correct engine "left" it
    profile = replace(PROFILES["quick"], seed=7, scan_amplitudes=(1e-5, 1e-2))
    checks, rows = amplitude_scan(profile, 2)
    (row,) = [r for r in rows if r["model"] == "coupled" and r["amplitude"] == 1e-2]
    assert 0.084 < row["reference_max_abs_angle"]
    assert abs(row["max_abs_angle"] / row["reference_max_abs_angle"] - 1) < 0.01
    assert not row["small_angle"] and not row["engine_left_regime"]
    status = {c.name: c.status for c in checks}
    assert status["agreement.small_angle_regime.coupled"] == "pass"


def test_an_engine_run_stopped_early_is_judged_over_the_common_span(monkeypatch):
    """An engine run that stopped where its state went non-finite (Exudyn at 0.3 m, quick
    profile, seed 7: 181 of 2000 samples) holds fewer samples than the reference and the
    twins: the scan compares every series over their common span, and the run's row is
    a breakdown beyond the small-angle regime, not a crash of the stage."""
    import validation.checks.agreement as agreement
    from cipcore.schema import Trajectory

    real = agreement.run_pair
    keep = 181

    def stopped(scn, target, **kw):
        full, red = real(scn, target, **kw)
        if scn.amplitude < 0.3:
            return full, red
        short = Trajectory(full.time[:keep], {k: v[:, :keep] for k, v in full.data.items()},
                           {**full.attrs, "max_abs_angle": [np.inf] * full.shape[0]})  # fmt: skip
        return short, red

    monkeypatch.setattr(agreement, "run_pair", stopped)
    profile = replace(PROFILES["smoke"], seed=7, scan_amplitudes=(1e-5, 0.3))
    checks, rows = amplitude_scan(profile, 2)
    late = [r for r in rows if r["amplitude"] == 0.3]
    assert len(late) == 2 and all(r["fell"] and not r["small_angle"] for r in late)
    assert all(np.isfinite(r["twin_relative_l2"]) for r in late)
    status = {c.name: c.status for c in checks}
    assert status["agreement.small_angle_regime.single"] == "pass"
    assert status["agreement.small_angle_regime.coupled"] == "pass"
