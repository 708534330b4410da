"""The engine contract: what every engine must do, as checks an engine's own CI can run.

``cip-validate contract --engine NAME`` (or ``--engine-cmd "CMD ARGS"`` for an
engine in another program) runs them and exits 0 when all pass, 1 when one
fails, 4 when the engine crashes; ``tests/test_engine_contract.py`` runs the
same functions for every registered engine.  Against the reduced reference
under the same noise draws, an engine must:

* reproduce the reduced trajectory within its declared precision at small
  amplitude (:func:`same_noise_gives_the_reduced_trajectory`);
* apply the control exactly d = tau/dt steps after the balancing error it
  uses, d computed here from tau and dt, never read from the engine
  (:func:`delay_is_tau_over_dt_steps`);
* hold the rod length (coupled rigid body; :func:`rod_holds_the_tips_together`);
* conserve energy without control or damping (rigid body;
  :func:`energy_is_conserved_without_control_or_damping`);
* give the same numbers for any batch split
  (:func:`same_seed_same_numbers_for_any_batch_split`).

Each check returns a one-line summary of what it measured, raises
:class:`ContractFailure` (an ``AssertionError``) when the engine breaks the
contract, or :class:`ContractSkip` when it does not apply to the engine.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import replace
from typing import Any

import numpy as np

from cip.model import CIPParams
from cipcore.models import get_model
from cipcore.noise import GainNoise
from cipcore.params import BalanceParams, EngineError
from cipcore.registry import REFERENCE, get_engine
from validation.checks.metrics import relative_l2

__all__ = ["CHECKS", "ContractFailure", "ContractSkip", "run_contract"]

P = BalanceParams(beta=20.306)


class ContractFailure(AssertionError):
    """The engine breaks the contract (the message says how)."""


class ContractSkip(Exception):
    """The check does not apply to this engine (the message says why)."""


def _require(ok: bool, message: str) -> None:
    if not ok:
        raise ContractFailure(message)


def same_noise_gives_the_reduced_trajectory(engine: Any, model: str) -> str:
    name = engine.name
    ref = get_engine(REFERENCE).simulate(model, P, 2.0, 2, seed=7, amplitude=1e-6)
    tr = engine.simulate(model, P, 2.0, 2, seed=7, amplitude=1e-6)
    _require(tr.attrs["engine"] == name, f"trajectory labelled {tr.attrs['engine']!r}")
    _require(tr["balancing_error"].shape == ref["balancing_error"].shape,
             f"shape {tr['balancing_error'].shape} != {ref['balancing_error'].shape}")  # fmt: skip
    dist = relative_l2(tr["balancing_error"], ref["balancing_error"])
    tol = engine.capabilities.trajectory_tolerance
    _require(dist <= tol, f"{name} {model}: distance {dist:.3e} > declared {tol:.1e}")
    if tol == 0.0:
        _require(np.array_equal(tr["balancing_error"], ref["balancing_error"]),
                 "declared exact (tolerance 0) but not bit-identical")  # fmt: skip
    return f"relative L2 distance {dist:.3e} <= declared {tol:.1e}"


def lag_residuals(engine: Any, integrator: str | None = None) -> tuple[int, dict[int, float]]:
    """Residual of the cart's response to the commanded force for lags around d = tau/dt.

    The cart velocity obeys, for any one-step integrator that holds the force
    F_n over step n (semi-implicit Euler, implicit, RK4, SAP) and a vanishing
    pendulum reaction (m/M = 1e-7), v(n+1) = a v(n) + b F_n / M with constants
    a, b of the stepper; a and b are fitted by least squares for each candidate
    lag of F_n = M beta R_n e(n - lag), so no stepper is assumed.

    Returns
    -------
    d : the expected lag (steps).
    resid : {lag: relative residual of the fit} for lags d - 3 .. d + 3.
    """
    p = BalanceParams(beta=20.306, nu=0.2)
    d = round(p.tau / p.dt)
    n_steps = 6 * d
    xi = GainNoise(3, 1, 1).next_chunk(n_steps)
    physical = CIPParams.from_reduced(p, mass_ratio=1e-7)
    if integrator is not None:
        physical = replace(physical, integrator=integrator)
    rigid = engine.capabilities.rigid_body  # the reference has no rigid body to set
    runner = engine.runner("single", p, 1, 1e-4, **({"physical": physical} if rigid else {}))
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
        resid[lag] = float(
            np.linalg.norm(v[n + 1] - a * v[n] - b * force) / np.linalg.norm(b * force)
        )
    return d, resid


def delay_is_tau_over_dt_steps(engine: Any, integrator: str | None = None) -> str:
    """The cart force at step n is beta R_n e(n - d) for d = round(tau/dt) and no other lag
    (estimated by :func:`lag_residuals`, which assumes no stepper)."""
    name = engine.name
    d, resid = lag_residuals(engine, integrator)
    best = min(resid, key=resid.get)
    _require(best == d, f"{name}: force follows e with lag {best} steps, expected {d}")
    _require(resid[d] < 1e-3, f"{name}: residual at lag {d} is {resid[d]:.2e} >= 1e-3")
    _require(min(resid[d - 1], resid[d + 1]) > 10 * resid[d],
             f"{name}: lag {d} does not stand out from {d - 1} and {d + 1}")  # fmt: skip
    near = min(resid[d - 1], resid[d + 1])
    return f"lag {d} steps (residual {resid[d]:.2e}; neighbours >= {near:.2e})"


def _rigid(engine: Any) -> None:
    if not engine.capabilities.rigid_body:
        raise ContractSkip(f"{engine.name} is not a rigid-body engine")


def rod_holds_the_tips_together(engine: Any) -> str:
    _rigid(engine)
    tr = engine.simulate("coupled", P, 2.0, 2, seed=5, amplitude=1e-3)
    tips = tr["tip_position"]
    mismatch = np.abs(tips[..., 0] - tips[..., 1]).max()
    scale = np.abs(tr["balancing_error"]).max()
    _require(mismatch < 1e-3 * scale,
             f"{engine.name}: tips apart by {mismatch:.2e} m (scale {scale:.2e})")  # fmt: skip
    return f"tips apart by at most {mismatch:.2e} m (< 1e-3 of {scale:.2e} m)"


def energy_is_conserved_without_control_or_damping(engine: Any) -> str:
    """beta = gamma = nu = 0: the falling inverted pendulum and cart conserve
    E = 1/2 M v_M^2 + 1/2 m |v_bob|^2 + m g L cos(theta) up to the integrator's
    O(dt) oscillation (semi-implicit Euler is symplectic: no secular drift)."""
    _rigid(engine)
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
    _require(th[-1] > 10 * th[0], "the pendulum should have fallen noticeably")
    drift = np.abs(energy - energy[0]).max() / kinetic.max()
    _require(drift < 2e-2, f"{engine.name}: energy changed by {drift:.2e} of the kinetic energy")
    return f"energy drift {drift:.2e} of the kinetic energy (< 2e-2)"


def same_seed_same_numbers_for_any_batch_split(engine: Any) -> str:
    if not engine.capabilities.deterministic:
        raise ContractSkip(f"{engine.name} declares itself non-deterministic")
    whole = engine.simulate("coupled", P, 0.5, 4, seed=11, amplitude=1e-3, threads=2)
    nc = get_model("coupled").n_controllers
    parts = [
        engine.simulate(
            "coupled", P, 0.5, noise=GainNoise(11, 2, nc, first_realization=k), amplitude=1e-3,
            threads=1,
        )["balancing_error"]
        for k in (0, 2)
    ]  # fmt: skip
    _require(np.array_equal(whole["balancing_error"], np.concatenate(parts)),
             f"{engine.name}: one batch of 4 differs from two batches of 2")  # fmt: skip
    return "bit-identical for one batch of 4 and two of 2"


#: check name -> function of the engine
CHECKS: dict[str, Callable[[Any], str]] = {
    "reduced_trajectory.single": lambda e: same_noise_gives_the_reduced_trajectory(e, "single"),
    "reduced_trajectory.coupled": lambda e: same_noise_gives_the_reduced_trajectory(e, "coupled"),
    "delay": delay_is_tau_over_dt_steps,
    "rod": rod_holds_the_tips_together,
    "energy": energy_is_conserved_without_control_or_damping,
    "batch_split": same_seed_same_numbers_for_any_batch_split,
}


def run_contract(engine: Any, on_check: Callable[[dict], None] | None = None) -> list[dict]:
    """Every check on ``engine``: rows {check, status (pass/fail/skipped/error), message,
    seconds}.  ``error`` is a crash of the engine (an exception other than a failure)."""
    rows = []
    broke = None  # an engine that broke (hung, exited, broke its protocol) is not run again
    for name, fn in CHECKS.items():
        t = time.perf_counter()
        try:
            if broke is not None:
                raise ContractSkip(f"not run: the engine broke in {broke}")
            status, msg = "pass", fn(engine)
        except ContractFailure as exc:
            status, msg = "fail", str(exc)
        except ContractSkip as exc:
            status, msg = "skipped", str(exc)
        except EngineError as exc:
            status, msg, broke = "error", " ".join(str(exc).split()), name
        except Exception as exc:  # the engine crashed
            status, msg = "error", f"{type(exc).__name__}: {exc}"
        row = {"check": name, "status": status, "message": msg,
               "seconds": round(time.perf_counter() - t, 2)}  # fmt: skip
        rows.append(row)
        if on_check:
            on_check(row)
    return rows
