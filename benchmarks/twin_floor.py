"""Each engine's floor against its exact twin, by amplitude, under the same noise.

    python benchmarks/twin_floor.py [--engines mujoco,mjx,drake] [--integrators Euler,RK4]
                                    [--models single,coupled] [--seed 1] [--realizations 4]
                                    [--duration 10] [--amplitudes 1e-8,1e-7,1e-6,1e-5,1e-4]

Prints, per engine, integrator, model and initial amplitude, the relative L2
distance of the balancing errors (engine vs its own twin,
:meth:`cip.engines.rigid_body.RigidBodyEngine.twin_terms`, and engine vs the paper's reduced
model), the rod's stretch against the twin's (coupled: relative L2, and the
stretch's RMS over the balancing error's, the measure for a twin whose rod is
rigid, :mod:`validation.checks.rod`) and the largest angle.
Below ~1e-7 m (coupled) the rod's absolute round-off sets the floor; above it
the angles' second-order terms (growing as amplitude^2).  Each engine's
``twin_tolerance`` is set from the floor at 1e-6 m (the check's amplitude).
An engine with its own stepper runs once, whatever ``--integrators`` says.
"""

from __future__ import annotations

import argparse

import numpy as np

from cip.mjcf_params import read_mapping
from cipcore.registry import availability
from cipcore.scenario import Recording, Scenario
from reduced import BalanceParams, simulate
from reduced.twin import TwinParams, simulate_twin
from validation.checks.agreement import model_file, rigid_engine
from validation.checks.metrics import relative_l2
from validation.profiles import PAPER_BETA


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--engines", default="mujoco")
    ap.add_argument("--integrators", default="Euler")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--realizations", type=int, default=4)
    ap.add_argument("--duration", type=float, default=10.0)
    ap.add_argument("--amplitudes", default="1e-8,1e-7,1e-6,1e-5,1e-4")
    ap.add_argument("--models", default=",".join(PAPER_BETA))
    a = ap.parse_args()
    print(f"{'engine':<12} {'integrator':<12} {'model':<8} {'amplitude':>9} {'engine-twin':>11} "
          f"{'rod':>9} {'stretch/e':>9} {'engine-reduced':>14} {'max|theta|':>10}")  # fmt: skip
    for name in a.engines.split(","):
        if availability(name) is not None:
            print(f"{name:<12} skipped: {availability(name)}")
            continue
        eng = rigid_engine(name)
        integrators = [i for i in a.integrators.split(",") if i in eng.integrators] or [None]
        for integ in integrators:
            for model in a.models.split(","):
                beta = PAPER_BETA[model]
                m = model_file(model, None, integ)
                mp = read_mapping(m)
                p = BalanceParams(beta=beta)
                tw = TwinParams(**eng.twin_terms(mp))
                for amp in (float(x) for x in a.amplitudes.split(",")):
                    f = ("balancing_error", "tip_position")
                    args = (a.duration, a.realizations, a.seed)
                    full = eng.simulate(model, p, *args, physical=mp.physical(), mj_model=m,
                                        fields=(*f, "angle"), amplitude=amp)  # fmt: skip
                    scn = Scenario(model, p, *args, amplitude=amp)
                    twin = simulate_twin(scn, tw, recording=Recording(fields=f))
                    er = simulate(scn, recording=Recording(fields=f))["balancing_error"]
                    ef, et = full["balancing_error"], twin["balancing_error"]
                    rod = ratio = float("nan")
                    if mp.n_controllers == 2:
                        sf = full["tip_position"][..., 0] - full["tip_position"][..., 1]
                        st = twin["tip_position"][..., 0] - twin["tip_position"][..., 1]
                        rod = relative_l2(sf, st)
                        ratio = float(np.sqrt(np.mean(sf**2) / np.mean(ef**2)))
                    print(f"{name:<12} {tw.integrator:<12} {model:<8} {amp:>9.0e} "
                          f"{relative_l2(ef, et):>11.2e} {rod:>9.2e} {ratio:>9.2e} "
                          f"{relative_l2(ef, er):>14.2e} "
                          f"{np.max(full.attrs['max_abs_angle']):>10.2e}", flush=True)  # fmt: skip


if __name__ == "__main__":
    main()
