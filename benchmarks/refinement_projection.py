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
import os
import sys
import time

import numpy as np

from validation.checks.agreement import model_file
from validation.checks.refinement import (
    FLOAT32_SETTINGS,
    PROJECTED,
    RefinementSetting,
    compare,
    excitation,
    parameter_projections,
    run_levels,
)
from validation.faults.catalogue import make_fault


def one_run(m, backend, rod: str, setting: RefinementSetting) -> tuple[dict, dict, float]:
    """(c from the nonlinear reference, c from the linear solution, E0) of one refinement
    run of ``backend`` (:func:`validation.checks.refinement.parameter_projections`)."""
    ctrl, exact, _ = excitation(m, rod, setting)
    runs = run_levels(m, backend, ctrl, setting)
    c, c_lin, _ = parameter_projections(m, rod, setting, runs)
    return c, c_lin, compare(runs, exact, [1.0] * len(runs)).e0


def _summary(c: np.ndarray) -> str:
    return (f"mean {c.mean():+.2e}, sd {c.std(ddof=1) if c.size > 1 else 0:.1e}, "
            f"range [{c.min():+.2e}, {c.max():+.2e}]")  # fmt: skip


def main(argv: list[str] | None = None) -> int:
    sys.path.insert(0, os.path.dirname(__file__))
    from refinement_power import _engine

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--engines", default="physx", help="comma list (mujoco-float32: the stand-in)")
    p.add_argument("--models", default="single,coupled", help="comma list")
    p.add_argument("--seeds", type=int, default=20, help="number of seeds")
    p.add_argument("--first-seed", type=int, default=1, help="the first seed")
    p.add_argument("--faults", default=",".join(PROJECTED), help="comma list of kinds ('' none)")
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
            cases = [("clean", None, None)] + [
                (f"{k} {float(z):g}", k, make_fault(k, float(z)))
                for k in a.faults.split(",") if k for z in a.sizes.split(",")
            ]  # fmt: skip
            print(f"{name} {model}: |e| {s.amplitude:g} m, {s.window:g} s, rod {rod}", flush=True)
            clean_max: dict[str, float] = {}
            for label, kind, fault in cases:
                if fault is not None and model not in fault.models:
                    continue
                backend = eng.rollout() if fault is None else fault.backend(eng.rollout())
                t = time.perf_counter()
                rows = [one_run(m, backend, rod, RefinementSetting(
                    seed, window=s.window, amplitude=s.amplitude))
                    for seed in range(a.first_seed, a.first_seed + a.seeds)]  # fmt: skip
                e0 = np.array([r[2] for r in rows])
                print(f"  {label}: E0 {e0.min():.2g}-{e0.max():.2g} "
                      f"({time.perf_counter() - t:.0f} s)", flush=True)  # fmt: skip
                for k in PROJECTED:
                    c = np.array([r[0][k] for r in rows])
                    c_lin = np.array([r[1][k] for r in rows])
                    if fault is None:
                        clean_max[k] = float(np.abs(c).max())
                    own = (f"; smallest / clean max |c| {c.min() / clean_max[k]:.1f}"
                           if kind == k and k in clean_max else "")  # fmt: skip
                    print(f"    c[{k}] {_summary(c)}{own}\n"
                          f"      linear only: {_summary(c_lin)}", flush=True)  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
