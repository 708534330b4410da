"""The time series' initial balancing error follows the engine's declared precision.

:meth:`validation.profiles.Profile.series_amplitude`: float64 engines run the
series at the profile's ``amplitude`` (1e-8 m), a float32 engine at
``amplitude_float32``: float32's round-off against the series falls as
1/amplitude, so it is the largest amplitude at which the rigid body's nonlinear
residual keeps float64 MuJoCo's twin metrics within their floor
(``validation.checks.agreement.FLOAT32_AMPLITUDE_RULE``).  The two tests that run
engines check both sides of that rule; they carry the ``warp`` marker (CI runs
them on warp's CPU device, ``CIPVAL_WARP_DEVICE=cpu pytest -m warp``): MuJoCo
Warp there takes minutes, the float64 side about a minute.
"""

from __future__ import annotations

import pytest
from helpers import engine_or_skip

from cipcore.params import BalanceParams
from cipcore.scenario import EngineTarget, Scenario
from validation.checks.agreement import (
    compare_series,
    run_pair,
    run_twin,
    series_metrics,
    trajectory_distance,
)
from validation.profiles import PAPER_BETA, PROFILES


def test_series_amplitude_follows_the_declared_precision() -> None:
    for profile in PROFILES.values():
        assert profile.series_amplitude("float64") == profile.amplitude == 1e-8
        assert profile.series_amplitude("float32") == profile.amplitude_float32
        assert profile.amplitude_float32 > profile.amplitude
    with pytest.raises(ValueError, match="precision must be one of"):
        PROFILES["quick"].series_amplitude("float16")


def _twin_metrics_status(amplitude: float) -> str:
    """twin.metrics of float64 MuJoCo's single series (quick profile's size) at ``amplitude``."""
    profile = PROFILES["quick"]
    model = "single"
    scn = Scenario(
        model,
        BalanceParams(beta=PAPER_BETA[model]),
        profile.series_duration,
        profile.series_realizations,
        profile.seed_for("series", model),
        amplitude,
    )
    run = {"decimate": profile.decimate, "threads": 1}
    full, red = run_pair(scn, EngineTarget(), **run)
    twin = run_twin(scn, EngineTarget(), **run)
    m = [series_metrics(x, profile, 0.1, profile.spectrum_segment) for x in (full, red, twin)]
    (check,) = [c for c in compare_series(model, *m[:2], "", "", m[2]) if c.name.startswith("twin")]
    return check.status


@pytest.mark.warp
def test_float32_amplitude_keeps_the_rigid_body_inside_the_twin_floor() -> None:
    """The nonlinear side: float64 MuJoCo's series at the quick profile's float32
    amplitude keeps every metric within the twin floor; at three times it, the angles'
    second-order terms move the spectral slopes past it (so the amplitude is the largest
    on the 1-3-10 grid, the best float32 resolution the floor allows)."""
    amplitude = PROFILES["quick"].amplitude_float32
    assert _twin_metrics_status(amplitude) == "pass"
    assert _twin_metrics_status(3 * amplitude) == "fail"


@pytest.mark.warp
def test_float32_engine_resolves_the_series_at_its_amplitude_only() -> None:
    """The round-off side: MuJoCo Warp (float32) at 1e-8 m fails the trajectory check's
    rule (relative L2 distance to the reduced model < 1 %; the coupled rod's float32
    resolution, about l * 6e-8 m, swamps the series), at its declared amplitude passes
    (2 realisations x 2 s)."""
    eng = engine_or_skip("mujoco-warp")
    profile = PROFILES["quick"]
    amplitude = profile.series_amplitude(eng.capabilities.precision)
    assert amplitude == profile.amplitude_float32
    model, window = "coupled", 2.0

    def distance(amp: float) -> float:
        scn = Scenario(model, BalanceParams(beta=PAPER_BETA[model]), window, 2, 7, amp)
        full, red = run_pair(scn, EngineTarget(eng.name), decimate=5, threads=1)
        return trajectory_distance(full, red, window)

    assert distance(profile.amplitude) > 0.01
    assert distance(amplitude) < 0.01
