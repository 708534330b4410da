"""One contract for every registered engine (skipped, with the reason, where unavailable).

Each engine must, against the reduced reference under the same noise draws:
reproduce the reduced trajectory within its declared precision at small
amplitude; apply the control exactly d = tau/dt steps after the balancing
error it uses (d computed here from tau and dt, never read from the engine);
hold the rod length (coupled rigid body); conserve energy without control or
damping (rigid body); give the same numbers for any batch split.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from cip.model import CIPParams
from cipcore.models import get_model
from cipcore.noise import ArrayNoise, GainNoise
from cipcore.params import BalanceParams
from cipcore.registry import REFERENCE, availability, engine_names, get_engine

P = BalanceParams(beta=20.306)


def _engine(name: str):
    reason = availability(name)
    if reason is not None:
        pytest.skip(f"engine {name!r} unavailable: {reason}")
    return get_engine(name)


ENGINES = engine_names()
RIGID = [n for n in ENGINES if n != REFERENCE]


def _distance(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.linalg.norm(a - b) / np.linalg.norm(b))


@pytest.mark.parametrize("name", ENGINES)
@pytest.mark.parametrize("model", ["single", "coupled"])
def test_same_noise_gives_the_reduced_trajectory(name: str, model: str) -> None:
    engine = _engine(name)
    ref = get_engine(REFERENCE).simulate(model, P, 2.0, 2, seed=7, amplitude=1e-6)
    tr = engine.simulate(model, P, 2.0, 2, seed=7, amplitude=1e-6)
    assert tr.attrs["engine"] == name
    assert tr["balancing_error"].shape == ref["balancing_error"].shape
    dist = _distance(tr["balancing_error"], ref["balancing_error"])
    tol = engine.capabilities.trajectory_tolerance
    assert dist <= tol, f"{name} {model}: distance {dist:.3e} > declared {tol:.1e}"
    if tol == 0.0:
        assert np.array_equal(tr["balancing_error"], ref["balancing_error"])


def _lag_residuals(name: str, integrator: str | None = None) -> tuple[int, dict[int, float]]:
    """Residual of the cart's response to the commanded force for lags around d.

    The cart velocity obeys, for any one-step integrator that holds the force
    F_n over step n (semi-implicit Euler, implicit, RK4, SAP) and a vanishing
    pendulum reaction (m/M = 1e-7), v(n+1) = a v(n) + b F_n / M with constants
    a, b of the stepper; a and b are fitted by least squares for each candidate
    lag of F_n = M beta R_n e(n - lag), so no stepper is assumed.
    """
    engine = _engine(name)
    p = BalanceParams(beta=20.306, nu=0.2)
    d = round(p.tau / p.dt)
    n_steps = 6 * d
    xi = GainNoise(3, 1, 1).next_chunk(n_steps)
    physical = CIPParams.from_reduced(p, mass_ratio=1e-7)
    if integrator is not None:
        physical = replace(physical, integrator=integrator)
    runner = engine.runner("single", p, 1, 1e-4, physical=physical)
    chunks = []
    for k in range(0, n_steps, runner.max_chunk if runner.max_chunk < n_steps else n_steps):
        chunks.append(runner.advance(xi[:, k : k + min(runner.max_chunk, n_steps - k)]))
    e = np.concatenate([c["balancing_error"] for c in chunks], axis=1)[0, :, 0]
    v = np.concatenate([c["base_velocity"] for c in chunks], axis=1)[0, :, 0]
    gain = p.beta * (1.0 + p.noise_scale * xi[0, : n_steps - 1, 0])
    n = np.arange(2 * d, n_steps - 1)
    resid = {}
    for lag in range(d - 3, d + 4):
        force = gain[n] * e[n - lag]
        (a, b), *_ = np.linalg.lstsq(np.column_stack([v[n], force]), v[n + 1], rcond=None)
        resid[lag] = np.linalg.norm(v[n + 1] - a * v[n] - b * force) / np.linalg.norm(b * force)
    return d, resid


@pytest.mark.parametrize("name", ENGINES)
def test_delay_is_tau_over_dt_steps(name: str) -> None:
    """The cart force at step n is beta R_n e(n - d) for d = round(tau/dt) and no other lag."""
    d, resid = _lag_residuals(name)
    best = min(resid, key=resid.get)
    assert best == d, f"{name}: force follows e with lag {best} steps, expected {d}: {resid}"
    assert resid[d] < 1e-3
    assert min(resid[d - 1], resid[d + 1]) > 10 * resid[d]


@pytest.mark.parametrize("integrator", ["RK4", "implicitfast"])
def test_delay_is_tau_over_dt_steps_for_any_integrator(integrator: str) -> None:
    """MuJoCo stepping RK4 or implicitfast applies the same delay (the estimator assumes
    no stepper)."""
    d, resid = _lag_residuals("mujoco", integrator)
    assert min(resid, key=resid.get) == d, resid
    assert resid[d] < 1e-3 and min(resid[d - 1], resid[d + 1]) > 10 * resid[d]


@pytest.mark.parametrize("name", RIGID)
def test_rod_holds_the_tips_together(name: str) -> None:
    engine = _engine(name)
    if not engine.capabilities.rigid_body:
        pytest.skip(f"{name} is not a rigid-body engine")
    tr = engine.simulate("coupled", P, 2.0, 2, seed=5, amplitude=1e-3)
    tips = tr["tip_position"]
    mismatch = np.abs(tips[..., 0] - tips[..., 1]).max()
    scale = np.abs(tr["balancing_error"]).max()
    assert mismatch < 1e-3 * scale, f"{name}: tips apart by {mismatch:.2e} m (scale {scale:.2e})"


@pytest.mark.parametrize("name", RIGID)
def test_energy_is_conserved_without_control_or_damping(name: str) -> None:
    """beta = gamma = nu = 0: the falling inverted pendulum and cart conserve
    E = 1/2 M v_M^2 + 1/2 m |v_bob|^2 + m g L cos(theta) up to the integrator's
    O(dt) oscillation (semi-implicit Euler is symplectic: no secular drift)."""
    engine = _engine(name)
    if not engine.capabilities.rigid_body:
        pytest.skip(f"{name} is not a rigid-body engine")
    p = BalanceParams(beta=0.0, gamma=0.0, nu=0.0)
    phys = CIPParams.from_reduced(p, mass_ratio=0.5)
    tr = engine.simulate("single", p, 0.6, 1, seed=0, amplitude=0.01, physical=phys)
    M, m, L, g = phys.cart_mass, phys.bob_mass, phys.pendulum_length, phys.gravity
    th = tr["angle"][0, :, 0]
    vm = tr["base_velocity"][0, :, 0]
    vtx = tr["tip_velocity"][0, :, 0]
    om = tr["balancing_error_velocity"][0, :, 0] / (L * np.cos(th))
    vtz = -L * np.sin(th) * om
    kinetic = 0.5 * M * vm**2 + 0.5 * m * (vtx**2 + vtz**2)
    energy = kinetic + m * g * L * np.cos(th)
    assert th[-1] > 10 * th[0], "the pendulum should have fallen noticeably"
    drift = np.abs(energy - energy[0]).max() / kinetic.max()
    assert drift < 2e-2, f"{name}: energy changed by {drift:.2e} of the kinetic energy"


@pytest.mark.parametrize("name", ENGINES)
def test_same_seed_same_numbers_for_any_batch_split(name: str) -> None:
    engine = _engine(name)
    if not engine.capabilities.deterministic:
        pytest.skip(f"{name} declares itself non-deterministic")
    whole = engine.simulate("coupled", P, 0.5, 4, seed=11, amplitude=1e-3, threads=2)
    nc = get_model("coupled").n_controllers
    parts = [
        engine.simulate(
            "coupled", P, 0.5, noise=GainNoise(11, 2, nc, first_realization=k), amplitude=1e-3,
            threads=1,
        )["balancing_error"]
        for k in (0, 2)
    ]  # fmt: skip
    assert np.array_equal(whole["balancing_error"], np.concatenate(parts))


def test_array_noise_and_gain_noise_agree_across_engines() -> None:
    """Handing the draws as an array changes nothing (the noise is the same value)."""
    xi = GainNoise(2, 2, 1).draws(500)
    a = get_engine(REFERENCE).simulate("single", P, 0.5, noise=ArrayNoise(xi, seed=2))
    b = get_engine(REFERENCE).simulate("single", P, 0.5, 2, seed=2)
    assert np.array_equal(a["balancing_error"], b["balancing_error"])


def test_engines_command_lists_every_engine_with_verdicts(tmp_path, capsys) -> None:
    """`cip-validate engines --json`, smoke size: verdicts, throughputs, skips with reasons."""
    import json

    from validation.cli import main

    rc = main(["engines", "--engines", "reduced,mujoco", "--profile", "smoke", "--json",
               "--out", str(tmp_path), "--no-figures"])  # fmt: skip
    res = json.loads(capsys.readouterr().out)
    rows = {r["engine"]: r for r in res["engines"]}
    assert set(rows) == {"reduced", "mujoco"}
    assert rc == (1 if res["status"] == "fail" else 0)
    m = rows["mujoco"]
    # the same direct checks as `run --engine mujoco`: its twin, rod, delay, declared model
    names = {c["name"] for c in m["checks"]}
    assert {"twin.trajectory.coupled", "twin.rod.coupled", "delay.single"} <= names
    assert not [f for f in m["failed"] if f.startswith(("twin.", "delay.", "model."))]
    assert m["twin_distance"]["coupled"] < m["twin_tolerance"]["coupled"]
    assert m["delay_steps"] == {"single": 100, "coupled": 100}
    assert m["throughput"]["ratio_to_mujoco"] == 1.0
    assert 0 < m["trajectory_distance"]["coupled"] < 1e-2
    assert rows["reduced"]["trajectory_distance"]["coupled"] == 0.0
    assert (tmp_path / "report.md").read_text().count("| mujoco |") == 1


def test_engines_command_rejects_an_unknown_engine(capsys) -> None:
    from validation.cli import main

    assert main(["engines", "--engines", "reduced,bullet"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "engine must be one of" in err[0] and "bullet" in err[0]


def test_an_absent_engine_is_listed_as_skipped_with_the_reason(monkeypatch) -> None:
    from cipcore import registry
    from validation.engines import compare_engines

    monkeypatch.setitem(registry.ENGINES, "absent", "cipval_no_such_module:ENGINE")
    res = compare_engines(["absent"], "smoke")
    (row,) = res["engines"]
    assert row["status"] == "skipped" and "cipval_no_such_module" in row["reason"]
