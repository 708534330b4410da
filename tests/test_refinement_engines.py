"""The engines that cipval has no exact twin for, each against the same checks (an engine
whose extra is absent is skipped with the reason; Newton's warp kernels run in CI's warp
step, ``pytest -m warp -n 0``; Genesis in ``.ci/genesis``).

Each declares the refinement tier; steps the single model as MuJoCo's semi-implicit
Euler with explicit dampers (to round-off in float64, to float32's floor in float32);
gives the same numbers in one chunk as in two; holds the coupled model's tips at the
rod's length; converges under time-step refinement to the exact zero-order-hold
solution at its precision's setting (:func:`validation.checks.refinement.precision_setting`);
fails that check with a 1e-3 error of the tip mass injected at its boundary (the
catalogue's ``mass_ratio`` fault around its backend); and is measured one step late
with the catalogue's latency fault.  What only one engine has (DART's and Genesis's
overflow, Genesis's parameter probe) is in that engine's own test module.
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np
import pytest
from helpers import engine_or_skip, forced, roll, tip_stretch

from cip.engines.drake_plant import geometry_from_mujoco
from cip.mjcf_params import read_mapping
from cipcore.params import BalanceParams
from validation.checks.agreement import measured_delay, model_file
from validation.checks.refinement import (
    FLOAT64_SETTING,
    REFINEMENT,
    precision_setting,
    refinement_check,
    tier,
)
from validation.checks.stats import FAIL, PASS
from validation.faults.catalogue import make_fault
from validation.profiles import PAPER_BETA


@dataclass(frozen=True)
class Expected:
    """What the engine declares and the tolerances its measured floors leave margin to.

    euler : relative L2 of (qpos, qvel) to mujoco.rollout (Euler) on the single model.
    stretch : largest |tip distance - rod length| (m) of the forced coupled model.
    """

    family: str
    precision: str
    euler: float
    stretch: float


EXPECTED = {
    # float64, MuJoCo's Euler to round-off (measured 1e-16 to 1e-15); the rod is cipval's
    # velocity projection on a constrained ABA step (stretch measured below 1e-12 m)
    "pinocchio": Expected("Pinocchio", "float64", 1e-12, 1e-10),
    "dart": Expected("DART", "float64", 1e-12, 1e-10),
    # float32: 6.1e-7 over 1 s (MuJoCo's Euler rounded to float32 every step: 5.7e-7); the
    # rod at float32's resolution of the tips' world positions near x = +-0.5 m (6e-8 m),
    # measured 9.0e-8 m
    "physx": Expected("PhysX", "float32", 2e-6, 2e-7),
    # float32 rounding (measured 5.2e-7); the projection on float32 coordinates, 4.4e-10 m
    "newton": Expected("Newton", "float32", 2e-6, 2e-9),
    # float64 (measured 5.6e-17); the projection's curvature term
    "genesis": Expected("Genesis", "float64", 1e-12, 1e-9),
}

ENGINES = [
    pytest.param(name, marks=pytest.mark.warp) if name == "newton" else name for name in EXPECTED
]


@pytest.fixture(params=ENGINES, scope="module")
def engine(request: pytest.FixtureRequest):
    """The registered engine (skipped, with the reason, where its extra is absent)."""
    return engine_or_skip(request.param)


def test_declares_refinement_tier(engine) -> None:
    caps, want = engine.capabilities, EXPECTED[engine.name]
    assert caps.family == want.family and caps.precision == want.precision
    assert caps.rigid_body and caps.twin is None and caps.rod == "rigid" and caps.order == 1.0
    assert caps.deterministic and engine.integrators == ()
    assert tier(caps)[0] == REFINEMENT


def test_single_model_is_mujoco_euler(engine) -> None:
    """Open-loop forces on the tilted single model: mujoco.rollout's (Euler) states, the
    second chunk continuing from the first's last state, and one chunk bit for bit."""
    from mujoco import rollout

    m, state, ctrl = forced("single", 2, 1000)
    out = roll(engine.rollout(), m, state, ctrl)
    ref, _ = rollout.rollout(m, mujoco.MjData(m), state, ctrl)
    np.testing.assert_allclose(out[..., 0], ref[..., 0], rtol=0, atol=1e-12)
    x, y = out[..., 1 : 1 + m.nq + m.nv], ref[..., 1 : 1 + m.nq + m.nv]
    assert np.linalg.norm(x - y) / np.linalg.norm(y) < EXPECTED[engine.name].euler
    if engine.capabilities.precision == "float32":
        assert np.array_equal(x.astype(np.float32), x)  # the engine's own float32 state
    whole = roll(engine.rollout(), m, state, ctrl, chunks=1)
    np.testing.assert_array_equal(whole[..., 1:], out[..., 1:])


def test_rod_holds_the_tips_at_its_length(engine) -> None:
    """The coupled model, both pendulums tilted and forced: the tips stay the rod's length
    apart (from the joint coordinates, in float64)."""
    m, state, ctrl = forced("coupled", 2, 1000)
    out = roll(engine.rollout(), m, state, ctrl)
    theta = out[..., 1 + np.array(geometry_from_mujoco(m).qpos_theta)]
    assert (np.abs(theta).max(axis=(0, 1)) > 0.01).all()  # both pendulums moved the rod
    assert np.abs(tip_stretch(m, out)).max() < EXPECTED[engine.name].stretch


@pytest.mark.parametrize("model", ["single", "coupled"])
def test_refinement_passes(engine, model: str) -> None:
    """Converges to the exact solution within its precision's floor, at least order 0.7
    (the declared order 1 less the check's slack); a float32 engine at its float32
    setting, order 1 within 0.1."""
    c = refinement_check(model, model_file(model), engine, 1)
    assert c.status == PASS, c.values
    floor = precision_setting(model, engine.capabilities.precision).floor
    assert c.values["e0_interval"][1] <= floor
    if engine.capabilities.precision == "float64":
        assert c.values["floor"] == FLOAT64_SETTING.floor and c.values["order"] >= 0.7
    else:
        assert c.values["setting"] == "float32" and abs(c.values["order"] - 1.0) < 0.1


def test_tip_mass_error_fails_refinement(engine) -> None:
    """A 1e-3 error of the tip mass at the engine's boundary: E0's interval above the floor."""
    fault = make_fault("mass_ratio", 1e-3)
    c = refinement_check("single", model_file("single"), engine, 1,
                         backend=fault.backend(engine.rollout()))  # fmt: skip
    assert c.status == FAIL, c.values
    assert c.values["e0_interval"][0] > c.values["floor"], c.values


def test_one_step_late_control_is_measured_late(engine) -> None:
    """The delay check's count: tau/dt = 100 steps, one more with the catalogue's latency
    fault wrapped around the engine's backend."""
    m = model_file("single")
    p = BalanceParams(beta=PAPER_BETA["single"])
    physical = read_mapping(m).physical()
    expected = round(p.tau / m.opt.timestep)
    assert measured_delay("single", p, physical, m, engine.rollout()) == expected
    late = make_fault("delay_late", 1).backend(engine.rollout())
    assert measured_delay("single", p, physical, m, late) == expected + 1
