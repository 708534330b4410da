"""How well each rigid-body engine holds the coupled model's rod: largest |tip distance - l|.

The planning scenario of the engine survey: both pendula at 0.05 rad, cart 1 at
0.2 m/s, no control (the pendula fall), 1 s at dt = 1 ms, the paper's rigid body
(M = 1 kg, m = 1e-3 kg, L = g/alpha = 0.4459 m, l = 1 m); and the closed loop
of the cross-engine rod check (paper coupled gain, 1e-3 m, 2 s, seed 0).

    python benchmarks/rod_stretch.py --engines mujoco,drake,bullet,exudyn,simbody
"""

from __future__ import annotations

import argparse

import mujoco
import numpy as np

from cip.engines.drake_plant import geometry_from_mujoco
from cip.model import CIPParams, build
from cip.runner import STATE_SPEC
from cipcore.params import BalanceParams
from cipcore.registry import availability, get_engine
from validation.profiles import PAPER_BETA


def rod_error(m: mujoco.MjModel, states: np.ndarray) -> np.ndarray:
    """|tip distance - l| (m) of MuJoCo states (..., nstate)."""
    g = geometry_from_mujoco(m)
    x = states[..., 1 + np.array(g.qpos_x)]
    th = states[..., 1 + np.array(g.qpos_theta)]
    L = np.array(g.pendulum_length)
    tx = np.array(g.cart_x0) + x + L * np.sin(th)
    tz = L * np.cos(th)
    return np.abs(np.hypot(tx[..., 0] - tx[..., 1], tz[..., 0] - tz[..., 1]) - g.rod_length)


def open_loop(name: str) -> float:
    p = CIPParams()
    m = build("coupled", p)
    g = geometry_from_mujoco(m)
    d = mujoco.MjData(m)
    for i in range(2):
        d.qpos[g.qpos_theta[i]] = 0.05
    d.qvel[g.dof_x[0]] = 0.2
    mujoco.mj_forward(m, d)
    s = np.empty(mujoco.mj_stateSize(m, STATE_SPEC))
    mujoco.mj_getState(m, d, s, STATE_SPEC)
    backend = get_engine(name).backend()(m, 1, 1)
    out = np.empty((1, 1000, s.size))
    backend(s[None], np.zeros((1, 1000, m.nu)), out)
    return float(rod_error(m, out).max())


def closed_loop(name: str) -> float:
    p = BalanceParams(beta=PAPER_BETA["coupled"])
    tr = get_engine(name).simulate("coupled", p, 2.0, 2, 0, amplitude=1e-3)
    L = CIPParams.from_reduced(p).pendulum_length
    tx = tr["tip_position"] + np.array([0.5, -0.5])
    tz = np.sqrt(L**2 - tr["balancing_error"] ** 2)
    return float(np.abs(np.hypot(tx[..., 0] - tx[..., 1], tz[..., 0] - tz[..., 1]) - 1.0).max())


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--engines", default="mujoco,drake,bullet,exudyn,simbody")
    a = ap.parse_args()
    print(f"{'engine':10s} {'open loop, 0.05 rad, 1 s':>26s} {'closed loop, 1e-3 m, 2 s':>26s}")
    for name in a.engines.split(","):
        why = availability(name)
        if why is not None:
            print(f"{name:10s} skipped: {why}")
            continue
        print(f"{name:10s} {open_loop(name):26.3e} {closed_loop(name):26.3e}", flush=True)


if __name__ == "__main__":
    main()
