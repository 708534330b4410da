"""The file protocol: a validation case for an engine that runs the controller itself.

``cip-validate case export`` writes ``case.npz``: the model files, the
parameters and every noise draw of the direct checks (the exact linear twin,
the rod, the measured delay).  The engine simulates each *scenario* of the case
with its own implementation of the paper's delayed random-gain control and
writes ``trajectories.npz``; ``cip-validate case check`` compares them with
the exact linear twin under the same draws and applies the same checks and
tolerances as ``cip-validate run`` (``twin.trajectory``, ``twin.rod``,
``delay``).  Nothing in it depends on numpy's random generator: the draws are
in the file.

``case.npz`` (version 1; every array float64 unless stated):

* ``format`` (string ``"cipval-case"``), ``version`` (int 1), ``case_json``
  (string: JSON of the scenarios, below);
* ``mjcf/<model>`` (string): the model file (MJCF) of ``single`` / ``coupled``;
* ``xi/<scenario>`` (R, N, C): the standard-normal draws xi_i(n) of every
  realisation r, step n and controller i.

Each scenario of ``case_json["scenarios"]`` has: ``name``, ``model``,
``n_realizations`` R, ``n_steps`` N, ``n_controllers`` C, ``dt`` (s),
``delay_steps`` d = tau/dt, ``beta``, ``noise_scale`` = nu / sqrt(dt),
``amplitude`` (m), ``history`` and ``record`` (fields to write), and per
controller ``cart_mass`` M_i (kg) and ``pendulum_length`` L_i (m).  The
engine simulates, for every realisation, N steps of the model file with:

* initial state: every pendulum at theta_i = arcsin(amplitude / L_i), carts at
  rest at their model positions, all velocities zero;
* balancing error e_i = L_i sin(theta_i) (m), its history before t = 0 equal
  to e_i(0) (``history`` ``"constant"``) or zero (``"zero"``);
* the control force on cart i over step n (eq. (3) with the paper's random
  gain): u_i(n) = (M_i beta) (1 + noise_scale xi_i(n)) e_i(n - d) (N), applied
  through actuator ``u_<i>`` and held over the step;
* recording: sample n of a field is the state *before* step n (sample 0 is
  the initial state).

``trajectories.npz``: ``<scenario>/<field>`` arrays (R, N, C) for the fields of
``record``: ``balancing_error`` e_i (m), ``tip_position`` (the cart's slide
coordinate ``x_M<i>`` plus e_i, m), ``base_velocity`` (the cart's velocity, m/s).
"""

from __future__ import annotations

import json
import math
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from cipcore.atomic import atomic_path
from cipcore.models import MODEL_NAMES, get_model
from cipcore.noise import ArrayNoise, GainNoise
from cipcore.params import BalanceParams, ParameterError
from cipcore.scenario import Recording, Scenario
from validation.checks.agreement import TWIN_AMPLITUDE, TWIN_WINDOW, model_file, rigid_engine
from validation.checks.metrics import relative_l2
from validation.checks.stats import FAIL, PASS, Check
from validation.profiles import PAPER_BETA

__all__ = ["FORMAT", "VERSION", "Case", "check_case", "export_case", "load_case", "run_case"]

FORMAT, VERSION = "cipval-case", 1
#: delay scenarios last this many delays (the control's first non-zero force lies in the first)
DELAY_CHUNKS = 3


@dataclass
class Case:
    """A loaded ``case.npz``: scenarios (dicts), model files by model, draws by scenario."""

    scenarios: list[dict[str, Any]]
    mjcf: dict[str, str]
    xi: dict[str, np.ndarray]
    seed: int

    def scenario(self, name: str) -> dict[str, Any]:
        return next(s for s in self.scenarios if s["name"] == name)


def _scenarios(model: str, mp, seed: int, n_realizations: int) -> tuple[list[dict], dict]:
    p = BalanceParams(beta=PAPER_BETA[model])
    phys = mp.physical()
    c = get_model(model).n_controllers
    base = {"model": model, "n_controllers": c, "dt": p.dt, "delay_steps": p.delay_steps,
            "noise_scale": p.noise_scale, "amplitude": TWIN_AMPLITUDE,
            "cart_mass": [phys.cart_mass] * c,
            "pendulum_length": [phys.pendulum_length] * c}  # fmt: skip
    n = round(TWIN_WINDOW / p.dt)
    twin = {**base, "name": f"twin.{model}", "n_realizations": n_realizations, "n_steps": n,
            "beta": p.beta, "history": "constant",
            "record": ["balancing_error", "tip_position"]}  # fmt: skip
    nd = DELAY_CHUNKS * p.delay_steps + 1
    delay = [{**base, "name": f"delay.{model}.{tag}", "n_realizations": 1, "n_steps": nd,
              "beta": beta, "noise_scale": 0.0, "history": "zero", "record": ["base_velocity"]}
             for tag, beta in (("on", p.beta), ("off", 0.0))]  # fmt: skip
    xi = {twin["name"]: GainNoise(seed, n_realizations, c).draws(n)}
    xi.update({s["name"]: np.zeros((1, nd, c)) for s in delay})
    return [twin, *delay], xi


def export_case(path: Path, seed: int = 1, n_realizations: int = 4,
                files: dict[str, str] | None = None) -> Case:  # fmt: skip
    """Write the direct checks' case (module docstring) to ``path``; returns it."""
    from cip.mjcf_params import read_mapping, shipped_model_path

    scenarios, xi, mjcf = [], {}, {}
    for model in MODEL_NAMES:
        src = (files or {}).get(model) or shipped_model_path(model)
        mjcf[model] = Path(src).read_text()
        s, x = _scenarios(model, read_mapping(model_file(model, files)), seed, n_realizations)
        scenarios += s
        xi.update(x)
    doc = {"scenarios": scenarios, "seed": seed, "models": list(mjcf)}
    arrays = {"format": np.array(FORMAT), "version": np.array(VERSION),
              "case_json": np.array(json.dumps(doc))}  # fmt: skip
    arrays.update({f"mjcf/{k}": np.array(v) for k, v in mjcf.items()})
    arrays.update({f"xi/{k}": v for k, v in xi.items()})
    with atomic_path(path) as tmp, open(tmp, "wb") as f:  # a file object: no ".npz" added
        np.savez(f, **arrays)
    return Case(scenarios, mjcf, xi, seed)


def load_case(path: Path | str) -> Case:
    """Read a ``case.npz``; a one-line :class:`ParameterError` when it is not one."""
    try:
        z = np.load(path, allow_pickle=False)
    except (OSError, ValueError) as exc:
        raise ParameterError(f"--case: cannot read {str(path)!r} ({exc})") from None
    with z:
        if "format" not in z.files or str(z["format"]) != FORMAT:
            raise ParameterError(f"--case: {str(path)!r} is not a cipval case file")
        if int(z["version"]) != VERSION:
            raise ParameterError(f"--case: {str(path)!r} is case version {int(z['version'])}, "
                                 f"this cipval reads version {VERSION}")  # fmt: skip
        doc = json.loads(str(z["case_json"]))
        mjcf = {m: str(z[f"mjcf/{m}"]) for m in doc["models"]}
        xi = {s["name"]: z[f"xi/{s['name']}"] for s in doc["scenarios"]}
    return Case(doc["scenarios"], mjcf, xi, int(doc["seed"]))


def _compiled(case: Case, model: str):
    import mujoco

    return mujoco.MjModel.from_xml_string(case.mjcf[model])


def run_case(case: Case, engine_name: str = "mujoco") -> dict[str, np.ndarray]:
    """The engine side of the file protocol, run by a registered rigid-body engine in process
    (the reference an external engine's ``trajectories.npz`` can be compared with)."""
    from cip.mjcf_params import read_mapping
    from cipcore.registry import get_engine

    engine = get_engine(engine_name)
    if not engine.capabilities.rigid_body:
        raise ParameterError(f"case run: engine {engine_name!r} is not a rigid-body engine")
    out: dict[str, np.ndarray] = {}
    for s in case.scenarios:
        m = _compiled(case, s["model"])
        phys = read_mapping(m).physical()
        p = BalanceParams(beta=s["beta"], nu=s["noise_scale"] * math.sqrt(s["dt"]), dt=s["dt"],
                          tau=s["delay_steps"] * s["dt"])  # fmt: skip
        if s["history"] == "constant":
            tr = engine.simulate(
                s["model"], p, s["n_steps"] * s["dt"], s["n_realizations"], case.seed,
                physical=phys, mj_model=m, noise=ArrayNoise(case.xi[s["name"]], seed=case.seed),
                amplitude=s["amplitude"], fields=tuple(s["record"]), threads=1,
            )  # fmt: skip
            for f in s["record"]:
                out[f"{s['name']}/{f}"] = np.ascontiguousarray(tr[f][:, : s["n_steps"]])
        else:  # zero history: a step in the balancing error at t = 0
            chunks = engine.runner(s["model"], p, s["n_realizations"], s["amplitude"],
                                   physical=phys)  # fmt: skip
            chunks.runner.e_hist[:] = 0.0
            chunks.runner.edot_hist[:] = 0.0
            xi, got, k = case.xi[s["name"]], [], 0
            while k < s["n_steps"]:
                n = min(chunks.max_chunk, s["n_steps"] - k)
                got.append(chunks.advance(xi[:, k : k + n]))
                k += n
            for f in s["record"]:
                out[f"{s['name']}/{f}"] = np.concatenate([g[f] for g in got], axis=1)
    return out


def _relative_l2(a: np.ndarray, b: np.ndarray) -> float:
    """As the run's twin check: over the common samples, ||a - b|| / ||b||."""
    k = min(a.shape[1], b.shape[1])
    rel = relative_l2(a[:, :k], b[:, :k])
    return rel if np.isfinite(rel) else float("inf")


def _get(traj: dict[str, np.ndarray], s: dict, field: str) -> np.ndarray:
    key = f"{s['name']}/{field}"
    if key not in traj:
        raise ParameterError(f"--trajectories: no array {key!r} (the case asks for it)")
    a = np.asarray(traj[key], dtype=float)
    want = (s["n_realizations"], s["n_steps"], s["n_controllers"])
    if a.shape != want:
        raise ParameterError(f"--trajectories: {key!r} has shape {a.shape}, expected {want}")
    return a


def check_case(case: Case, traj: dict[str, np.ndarray], engine: str = "mujoco") -> list[Check]:
    """The run's direct checks on an engine's trajectories (module docstring).

    ``engine`` names the registered rigid-body engine whose discretisation the
    trajectories claim (the case's model file stepped as that engine steps it):
    its measured twin and rod tolerances apply.
    """
    from cip.mjcf_params import read_mapping
    from reduced.twin import TwinParams, simulate_twin

    declared = rigid_engine(engine)  # a bad name is one line before any work
    checks = []
    for model in case.mjcf:
        mp = read_mapping(_compiled(case, model))
        twin_p = TwinParams(**mp.twin_terms())
        s = case.scenario(f"twin.{model}")
        p = BalanceParams(beta=s["beta"], nu=s["noise_scale"] * math.sqrt(s["dt"]), dt=s["dt"],
                          tau=s["delay_steps"] * s["dt"])  # fmt: skip
        ef = _get(traj, s, "balancing_error")
        tips = _get(traj, s, "tip_position")
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            twin = simulate_twin(
                Scenario(
                    model,
                    p,
                    s["n_steps"] * s["dt"],
                    s["n_realizations"],
                    case.seed,
                    amplitude=s["amplitude"],
                ),
                twin_p,
                noise=ArrayNoise(case.xi[s["name"]], seed=case.seed),
                recording=Recording(fields=("balancing_error", "tip_position")),
            )
        et = twin["balancing_error"]
        complete = bool(ef.shape[1] == et.shape[1] and np.isfinite(ef).all())
        rel = _relative_l2(ef, et)
        details = (f"case file: amplitude {s['amplitude']:g} m, {s['n_realizations']} x "
                   f"{s['n_steps'] * s['dt']:g} s, seed {case.seed}, the case's draws")  # fmt: skip
        twin_tol, rod_tol = declared.twin_tolerance_for(model), declared.rod_tolerance
        checks.append(Check(
            f"twin.trajectory.{model}", PASS if complete and rel <= twin_tol else FAIL,
            {"relative_l2": rel, "complete": complete},
            tolerance=f"relative L2 distance of the balancing errors to the exact linear twin "
            f"<= {twin_tol:g} ({engine}'s measured floor)", details=details,
        ))  # fmt: skip
        if s["n_controllers"] == 2:
            sf = tips[..., 0] - tips[..., 1]
            st = twin["tip_position"][..., 0] - twin["tip_position"][..., 1]
            rel_rod = _relative_l2(sf, st)
            checks.append(Check(
                f"twin.rod.{model}", PASS if complete and rel_rod <= rod_tol else FAIL,
                {"stretch_relative_l2": rel_rod},
                tolerance="the rod's stretch (tip 1 - tip 2) matches the twin's soft constraint "
                f"to relative L2 <= {rod_tol:g}", details=details,
            ))  # fmt: skip
        on, off = (case.scenario(f"delay.{model}.{t}") for t in ("on", "off"))
        v_on, v_off = _get(traj, on, "base_velocity")[0], _get(traj, off, "base_velocity")[0]
        moved = np.flatnonzero(np.abs(v_on - v_off).max(axis=1) > 0)
        got = int(moved[0]) - 1 if moved.size else -1  # sample n + 1 is the state after step n
        expected = on["delay_steps"]
        checks.append(Check(
            f"delay.{model}", PASS if got == expected else FAIL,
            {"measured_steps": got, "expected_steps": expected},
            tolerance="a step in the balancing error reaches the control force exactly "
            "tau / timestep steps later", details="zero history, no noise, beta on and off",
        ))  # fmt: skip
    return checks
