"""Bullet, Exudyn and Simbody against their exact twins (``reduced._twin_schemes``).

Each engine declares its discretisation (Exudyn: Newmark beta = 1/2, gamma = 1
with a rigid index-3 rod; Simbody: fixed-step Runge-Kutta-Merson with a rigid
rod; Bullet: semi-implicit Euler with its velocity-level rod row); at 1e-6 m the
engine matches that twin to its declared ``twin_tolerance``, while the twin of
another discretisation (semi-implicit Euler with MuJoCo's soft rod, what these
engines were held to before they declared theirs) is orders of magnitude off.
The rod's stretch is held by :func:`validation.checks.rod.rod_check`.  A one-step
delay error at each engine's boundary fails the twin check in
``tests/test_engine_families.py``.
"""

from __future__ import annotations

import functools

import numpy as np
import pytest

from cip.mjcf_params import read_mapping
from cipcore.params import BalanceParams
from cipcore.registry import availability, get_engine
from cipcore.scenario import Recording, Scenario
from reduced.twin import TwinParams, simulate_twin
from validation.checks.agreement import model_file
from validation.checks.metrics import relative_l2
from validation.checks.rod import rod_check
from validation.checks.stats import FAIL, PASS
from validation.profiles import PAPER_BETA

FAMILIES = ("bullet", "exudyn", "simbody")
AMPLITUDE = 1e-6  # m, the twin check's amplitude
FIELDS = ("balancing_error", "tip_position")


def _engine(name: str):
    reason = availability(name)
    if reason is not None:
        pytest.skip(f"engine {name!r} unavailable: {reason}")
    return get_engine(name)


@functools.cache
def _pair(name: str, model: str, duration: float = 1.0):
    eng = get_engine(name)
    m = model_file(model)
    mp = read_mapping(m)
    p = BalanceParams(beta=PAPER_BETA[model])
    full = eng.simulate(model, p, duration, 1, 5, physical=mp.physical(), mj_model=m,
                        fields=FIELDS, amplitude=AMPLITUDE)  # fmt: skip
    tw = TwinParams(**eng.twin_terms(mp))
    twin = simulate_twin(
        Scenario(model, p, duration, 1, 5, amplitude=AMPLITUDE),
        tw,
        recording=Recording(fields=FIELDS),
    )
    return full, twin, tw, mp, p


@pytest.mark.parametrize("model", ["single", "coupled"])
@pytest.mark.parametrize("name", FAMILIES)
def test_engine_matches_its_own_twin_and_not_another(name: str, model: str) -> None:
    eng = _engine(name)
    full, twin, tw, mp, p = _pair(name, model)
    rel = relative_l2(full["balancing_error"], twin["balancing_error"])
    assert rel <= eng.twin_tolerance_for(model), f"{name} {model}: {rel:.3e}"
    other = TwinParams(**{**mp.twin_terms(), "integrator": "Euler"})
    if other == tw:
        return  # Bullet's single model: semi-implicit Euler is its own twin
    far = simulate_twin(
        Scenario(model, p, 1.0, 1, 5, amplitude=AMPLITUDE),
        other,
        recording=Recording(fields=FIELDS),
    )
    off = relative_l2(full["balancing_error"], far["balancing_error"])
    assert off > 30 * eng.twin_tolerance_for(model), f"{name} {model}: other twin {off:.3e}"


@pytest.mark.parametrize("name", FAMILIES)
def test_rigid_rod_stretch_is_held_and_a_missing_rod_fails(name: str) -> None:
    """The stretch of a rod the twin holds rigid is the engine's round-off, far below its
    rod_tolerance; a stretch of the balancing error's size (no rod) fails."""
    eng = _engine(name)
    full, twin, tw, _, _ = _pair(name, "coupled")
    assert tw.rod and tw.rod_regulariser == 0.0
    sf = full["tip_position"][..., 0] - full["tip_position"][..., 1]
    st = twin["tip_position"][..., 0] - twin["tip_position"][..., 1]
    ef = full["balancing_error"]
    args = (tw, (eng.capabilities.rod, eng.rod_tolerance))
    held = rod_check("coupled", sf, st, ef, *args)
    assert held.status == PASS, held
    assert held.values["stretch_over_balancing_error"] < eng.rod_tolerance / 10, held
    loose = ef[..., 0] - ef[..., 1] + 1e-3 * np.abs(ef[..., 0])  # tips free of each other
    assert rod_check("coupled", loose, st, ef, *args).status == FAIL
    stopped = ef.copy()
    stopped[0, -1, 0] = np.nan  # a run that ended in a non-finite state
    assert rod_check("coupled", sf, st, stopped, *args).status == FAIL
    assert rod_check("coupled", sf[:, :-1], st, ef[:, :-1], *args).status == FAIL  # cut short


def test_a_soft_twin_rod_is_compared_by_relative_distance() -> None:
    """A twin rod with a regulariser (MuJoCo's, Drake's) resolves its stretch: the check is
    the relative L2 distance of the stretches."""
    mp = read_mapping(model_file("coupled"))
    tw = TwinParams(**mp.twin_terms())
    assert tw.rod_regulariser > 0
    rng = np.random.default_rng(0)
    st = rng.normal(size=(2, 50)) * 1e-10
    ef = rng.normal(size=(2, 50, 2)) * 1e-6
    assert rod_check("coupled", st * 1.001, st, ef, tw, ("soft", 1e-2)).status == PASS
    bad = rod_check("coupled", st * 1.1, st, ef, tw, ("soft", 1e-2))
    assert bad.status == FAIL and bad.values["stretch_relative_l2"] == pytest.approx(0.1)


def test_a_model_the_engine_refuses_counts_as_flagged_in_the_selftest() -> None:
    """Exudyn's point-mass bob refuses the bob-inertia fault with a one-line error; the
    selftest counts the refusal as the fault flagged (it cannot pass unnoticed)."""
    from validation.faults.catalogue import make_fault
    from validation.faults.selftest import flagged_by

    _engine("exudyn")
    by = flagged_by(make_fault("bob_inertia", 1e-4), 1, 1, "exudyn")
    assert len(by) == 1 and by[0].startswith("engine refused the model") and "point mass" in by[0]
