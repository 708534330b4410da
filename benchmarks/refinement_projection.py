"""The refinement error projected on each parameter's direction: a matched filter (issue 41).

The refinement check (:mod:`validation.checks.refinement`) judges an engine by E0, the
relative L2 distance of its dt -> 0 limit y0 to the exact zero-order-hold solution x.
For a float32 engine that distance is mostly rounding noise (the float32 floors, 1.2e-4
single and 1.6e-4 coupled), and a 1e-4 error of a damper moves E0 by less than that.
But a wrong parameter moves y0 along one direction: the exact solution's sensitivity
s_k = (x(p_k (1 + d)) - x(p_k)) / d to a relative change d of parameter k (the fault
catalogue's model edits, :func:`validation.faults.catalogue.make_fault`, at d = 1e-3).
The rounding noise is spread over every direction, so its projection on s_k,

    c_k = <y0 - x, s_k> / <s_k, s_k>,

the relative error of parameter k that best explains the engine's deviation alone, is
far smaller than E0.  This script runs the check's own setting (the float32 setting
of the model, :data:`validation.checks.refinement.FLOAT32_SETTINGS`, the same forces,
levels and extrapolation) for the clean engine and for faults injected at its boundary,
and prints c_k per parameter: its mean and spread over seeds, and the largest |c_k| of
the clean engine beside the smallest c_k of each fault along its own direction.  The
directions of the tip damping, the bob's mass and gravity are nearly parallel in the
single model, so a fault shows on all of them: c_k detects that a parameter is wrong
more than which one.

    python benchmarks/refinement_projection.py --engines physx --models single,coupled
    python benchmarks/refinement_projection.py --engines mujoco-float32 --seeds 3
"""

from __future__ import annotations

import argparse
import copy
import os
import sys
import time

import mujoco
import numpy as np

from cip.linearize import rod_jacobians
from reduced.zoh import zoh_response
from validation.checks.agreement import model_file
from validation.checks.refinement import (
    FLOAT32_SETTINGS,
    ROUNDOFF,
    RefinementSetting,
    extrapolate,
    observable,
    open_loop_forces,
    run_levels,
)
from validation.faults.catalogue import make_fault

#: the parameters whose directions are projected on (fault catalogue kinds)
DIRECTIONS = ("tip_damping", "cart_damping", "mass_ratio", "pendulum_length", "gravity")
#: the relative change that defines a direction
STEP = 1e-3


def directions(m: mujoco.MjModel, model: str, rod: str) -> list[tuple[str, tuple]]:
    """(kind, the linearisation (A, B) of the model file with that parameter changed by
    :data:`STEP`, the rod as ``rod``) for each of :data:`DIRECTIONS` that applies to
    ``model``: the same at every seed, so computed once."""
    out = []
    for kind in DIRECTIONS:
        fault = make_fault(kind, STEP)
        if model not in fault.models or fault.edit_model is None:
            continue
        fm = copy.deepcopy(m)
        fault.edit_model(fm)
        mujoco.mj_setConst(fm, mujoco.MjData(fm))
        out.append((kind, rod_jacobians(fm, rod)))
    return out


def projections(m, backend, ab, setting: RefinementSetting, dirs) -> tuple[dict, float]:
    """c_k per direction and E0 of one refinement run (module docstring); ``ab`` the
    model file's linearisation, ``dirs`` from :func:`directions`."""
    h = float(m.opt.timestep)
    k_int = round(setting.window / h)
    motors, obs = observable(m)
    ctrl = np.zeros((setting.n_realizations, k_int, m.nu))
    f = open_loop_forces(setting.n_realizations, k_int, len(motors), h, setting.seed)
    for i, motor in enumerate(motors):
        ctrl[..., motor] = f[..., i]
    x0 = np.zeros((setting.n_realizations, m.nq + m.nv))

    def exact_of(a: np.ndarray, b: np.ndarray) -> np.ndarray:
        return zoh_response(a, b, x0, ctrl, h)[..., : m.nq] @ obs.T

    exact = exact_of(*ab)
    scale = setting.amplitude / np.abs(exact[..., 1::2]).max(axis=(1, 2), keepdims=True)
    sens = {kind: (exact_of(*abk) - exact) * scale / STEP for kind, abk in dirs}
    exact, ctrl = exact * scale, ctrl * scale
    y0 = extrapolate(run_levels(m, backend, ctrl, setting), ROUNDOFF)[0]
    e = (y0 - exact).ravel()
    c = {k: float(e @ s.ravel() / (s.ravel() @ s.ravel())) for k, s in sens.items()}
    return c, float(np.linalg.norm(e) / np.linalg.norm(exact))


def main(argv: list[str] | None = None) -> int:
    sys.path.insert(0, os.path.dirname(__file__))
    from refinement_power import _engine

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--engines", default="physx", help="comma list (mujoco-float32: the stand-in)")
    p.add_argument("--models", default="single,coupled", help="comma list")
    p.add_argument("--seeds", type=int, default=20, help="seeds 1..N")
    p.add_argument("--faults", default="tip_damping,cart_damping", help="comma list of kinds")
    p.add_argument("--sizes", default="1e-4,3e-5", help="comma list of relative sizes")
    a = p.parse_args(argv)
    load = os.getloadavg()
    print(f"# load {load[0]:.2f} {load[1]:.2f} {load[2]:.2f}", flush=True)
    for name in a.engines.split(","):
        eng = _engine(name)
        if eng is None:
            continue
        rod = "soft" if eng.capabilities.rod == "soft" else "rigid"
        for model in a.models.split(","):
            m, s = model_file(model), FLOAT32_SETTINGS[model]
            dirs, ab = directions(m, model, rod), rod_jacobians(m, rod)
            cases = [("clean", None, None)] + [
                (f"{k} {float(z):g}", k, make_fault(k, float(z)))
                for k in a.faults.split(",") for z in a.sizes.split(",")
            ]  # fmt: skip
            print(f"{name} {model}: |e| {s.amplitude:g} m, {s.window:g} s", flush=True)
            clean_max = {}
            for label, kind, fault in cases:
                if fault is not None and model not in fault.models:
                    continue
                backend = eng.rollout() if fault is None else fault.backend(eng.rollout())
                t = time.perf_counter()
                rows = [projections(m, backend, ab, RefinementSetting(
                    seed, window=s.window, amplitude=s.amplitude), dirs)
                    for seed in range(1, a.seeds + 1)]  # fmt: skip
                e0 = np.array([r[1] for r in rows])
                print(f"  {label}: E0 {e0.min():.2g}-{e0.max():.2g} "
                      f"({time.perf_counter() - t:.0f} s)", flush=True)  # fmt: skip
                for k, _ in dirs:
                    c = np.array([r[0][k] for r in rows])
                    if fault is None:
                        clean_max[k] = float(np.abs(c).max())
                    own = (f"; smallest / clean max |c| {c.min() / clean_max[k]:.1f}"
                           if kind == k else "")  # fmt: skip
                    print(f"    c[{k}] mean {c.mean():+.2e}, sd {c.std(ddof=1):.1e}, range "
                          f"[{c.min():+.2e}, {c.max():+.2e}]{own}", flush=True)  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
