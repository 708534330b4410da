#!/usr/bin/env python3
"""Reference engine for cipval's file protocol (case version 1), as a separate program.

    cip-validate case export --out case.npz
    python examples/case_engine.py case.npz trajectories.npz
    cip-validate case check --case case.npz --trajectories trajectories.npz

The engine runs the controller itself: for every scenario of the case it
simulates the model file with the paper's delayed random-gain control
u_i(n) = (M_i beta) (1 + noise_scale xi_i(n)) e_i(n - d), e_i = L_i sin(theta_i),
from the case's own noise draws, and records the state before each step
(the conventions are in cipval's README, "Engines that run the controller
themselves").  This one steps the model with MuJoCo's ``mj_step``; it
imports nothing from cipval: only the standard library, numpy and mujoco.

``--delay-error`` uses e_i(n - d - 1) instead: a one-step delay fault that
``case check`` must catch.
"""

import argparse
import json

import mujoco
import numpy as np


def simulate(model: mujoco.MjModel, s: dict, xi: np.ndarray, late: int) -> dict:
    c, d, n_steps = s["n_controllers"], s["delay_steps"], s["n_steps"]
    joint = lambda name: model.joint(name)  # noqa: E731
    qx = [model.jnt_qposadr[joint(f"x_M{i + 1}").id] for i in range(c)]
    qt = [model.jnt_qposadr[joint(f"theta_{i + 1}").id] for i in range(c)]
    vx = [model.jnt_dofadr[joint(f"x_M{i + 1}").id] for i in range(c)]
    act = [model.actuator(f"u_{i + 1}").id for i in range(c)]
    M = np.array(s["cart_mass"])
    L = np.array(s["pendulum_length"])
    out = {f: np.empty((s["n_realizations"], n_steps, c)) for f in s["record"]}
    data = mujoco.MjData(model)
    for r in range(s["n_realizations"]):
        mujoco.mj_resetData(model, data)
        data.qpos[qt] = np.arcsin(s["amplitude"] / L)
        mujoco.mj_forward(model, data)
        e0 = L * np.sin(data.qpos[qt])
        hist = [np.zeros(c) if s["history"] == "zero" else e0.copy()] * (d + late)
        for n in range(n_steps):
            e = L * np.sin(data.qpos[qt])
            for f in s["record"]:
                if f == "balancing_error":
                    out[f][r, n] = e
                elif f == "tip_position":
                    out[f][r, n] = data.qpos[qx] + e  # cart slide coordinate + e
                elif f == "base_velocity":
                    out[f][r, n] = data.qvel[vx]
            delayed = hist[n]  # e(n - d - late): the history holds d + late values before n
            hist.append(e)
            data.ctrl[act] = (M * s["beta"]) * (1.0 + s["noise_scale"] * xi[r, n]) * delayed
            mujoco.mj_step(model, data)
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("case")
    ap.add_argument("out")
    ap.add_argument("--delay-error", action="store_true", help="use e(n - d - 1): one step late")
    a = ap.parse_args()
    z = np.load(a.case)
    if str(z["format"]) != "cipval-case" or int(z["version"]) != 1:
        raise SystemExit("case_engine: this engine reads cipval-case version 1 only")
    doc = json.loads(str(z["case_json"]))
    models = {m: mujoco.MjModel.from_xml_string(str(z[f"mjcf/{m}"])) for m in doc["models"]}
    result = {}
    for s in doc["scenarios"]:
        got = simulate(models[s["model"]], s, z[f"xi/{s['name']}"], int(a.delay_error))
        result.update({f"{s['name']}/{f}": v for f, v in got.items()})
    np.savez(a.out, **result)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
