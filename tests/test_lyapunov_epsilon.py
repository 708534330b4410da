"""lambda1's Benettin deviation follows the engine's declared precision.

:meth:`validation.profiles.Profile.lyapunov_epsilon`: float64 engines keep
``benettin_epsilon`` (1e-7 m), a float32 engine runs at
``benettin_epsilon_float32`` (5e-4 m): float32 resolves the coupled rod's length
only to about ulp(1 m) = 1.2e-7 m, so at 1e-7 m the rod's constraint force is
round-off in the tangent dynamics (``validation.checks.agreement.FLOAT32_EPSILON_RULE``).
The MuJoCo Warp test carries the ``warp`` marker (CI runs it on warp's CPU
device, ``CIPVAL_WARP_DEVICE=cpu pytest -m warp``; about 20 s there).
"""

from __future__ import annotations

from dataclasses import replace

import pytest
from helpers import engine_or_skip

from cip.mjcf_params import read_mapping
from cipcore.registry import get_engine
from reduced import BalanceParams
from validation.checks import agreement
from validation.checks.agreement import lyapunov_checks, model_file
from validation.profiles import PROFILES


def test_lyapunov_epsilon_follows_the_declared_precision() -> None:
    for profile in PROFILES.values():
        assert profile.lyapunov_epsilon("float64") == profile.benettin_epsilon == 1e-7
        assert profile.lyapunov_epsilon("float32") == profile.benettin_epsilon_float32 == 5e-4
    with pytest.raises(ValueError, match="precision must be one of"):
        PROFILES["quick"].lyapunov_epsilon("float16")


class _Declared:
    """A registered engine with another declared precision (everything else its own)."""

    def __init__(self, engine, precision: str) -> None:
        self._engine = engine
        self.capabilities = replace(engine.capabilities, precision=precision)
        self.epsilons: list[float] = []

    def __getattr__(self, name: str):
        return getattr(self._engine, name)

    def lyapunov(self, *args, **options):
        self.epsilons.append(options["epsilon"])
        return self._engine.lyapunov(*args, **options)


@pytest.mark.parametrize("precision, epsilon", [("float64", 1e-7), ("float32", 5e-4)])
def test_lyapunov_checks_run_the_engine_at_its_precisions_epsilon(
    monkeypatch: pytest.MonkeyPatch, precision: str, epsilon: float
) -> None:
    """The lambda1 stage hands the engine its precision's deviation and says so; float64
    MuJoCo's lambda1 moves by far less than its interval between the two (linear)."""
    engine = _Declared(get_engine("mujoco"), precision)
    monkeypatch.setattr(agreement, "rigid_engine", lambda name: engine)
    profile = replace(PROFILES["smoke"], lyapunov_gains={"coupled": (20.5,)}, lyapunov_duration=4.0)
    (check,), _ = lyapunov_checks(profile, 1)
    assert engine.epsilons == [epsilon]
    assert f"Benettin deviation {epsilon:g} m" in check.details
    assert ("float32's deviation" in check.details) == (precision == "float32")
    full = check.values["full"]
    m = model_file("coupled")
    own = get_engine("mujoco").lyapunov(
        "coupled", BalanceParams(beta=20.5), 4.0, profile.lyapunov_realizations,
        profile.seed_for("lyapunov", "coupled", 20.5), threads=1, epsilon=1e-7,
        mj_model=m, physical=read_mapping(m).physical(),
    )  # fmt: skip
    assert (full["value"] == own.lambda1) == (epsilon == 1e-7)
    assert abs(full["value"] - own.lambda1) < 1e-6 < own.ci95[1] - own.ci95[0]


@pytest.mark.warp
def test_float32_epsilon_resolves_the_coupled_rod() -> None:
    """MuJoCo Warp's coupled lambda1 (1 realisation x 2 s, beta 20.5) at float64's 1e-7 m
    is 0.53 1/s off float64 MuJoCo's (-0.675 1/s); at its float32 deviation 1.7e-3."""
    eng = engine_or_skip("mujoco-warp")
    epsilon = PROFILES["smoke"].lyapunov_epsilon(eng.capabilities.precision)
    args = ("coupled", BalanceParams(beta=20.5), 2.0, 1, 823276866)
    m = model_file("coupled")
    kw = {"threads": 1, "mj_model": m, "physical": read_mapping(m).physical()}
    ref = get_engine("mujoco").lyapunov(*args, epsilon=1e-7, **kw).lambda1

    def off(eps: float) -> float:
        return abs(eng.lyapunov(*args, epsilon=eps, **kw).lambda1 - ref)

    assert off(epsilon) < 0.02
    assert off(1e-7) > 0.2
