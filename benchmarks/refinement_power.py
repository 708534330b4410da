"""The refinement tier's floor and power: E0 of correct engines over seeds, and faults.

For each engine of the registry that is installed (and MuJoCo with each of its
integrators), runs :func:`validation.checks.refinement.refinement_check` on both
shipped models at ``--seeds`` seeds (the false-failure count of a correct engine),
then, at one seed, the engine with each fault of ``--faults`` at the sizes of
``--sizes`` (relative) injected at its boundary: the smallest flagged size per fault.

    python benchmarks/refinement_power.py [--engines mujoco,drake] [--seeds 20]
        [--faults mass_ratio,pendulum_length,gravity,tip_damping,cart_damping]
        [--sizes 1e-3,1e-4,1e-5,1e-6]
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--engines", default="mujoco")
    ap.add_argument("--integrators", default="Euler,implicitfast,RK4",
                    help="MuJoCo-family engines: each of these integrators")  # fmt: skip
    ap.add_argument("--seeds", type=int, default=20)
    ap.add_argument(
        "--faults", default="mass_ratio,pendulum_length,gravity,tip_damping,cart_damping"
    )
    ap.add_argument("--sizes", default="1e-3,1e-4,1e-5,1e-6")
    ap.add_argument("--models", default="single,coupled")
    a = ap.parse_args()
    from cipcore.registry import get_engine
    from validation.checks.agreement import model_file
    from validation.checks.refinement import refinement_check
    from validation.faults.catalogue import make_fault

    print(f"# load {' '.join(f'{x:.2f}' for x in os.getloadavg())}", flush=True)
    for name in a.engines.split(","):
        eng = get_engine(name)
        why = eng.unavailable()
        if why:
            print(f"{name}: skipped ({why})")
            continue
        integrators = a.integrators.split(",") if len(eng.integrators) > 1 else [None]
        for integ in integrators:
            label = name + (f" ({integ})" if integ else "")
            for model in a.models.split(","):
                m = model_file(model, None, integ)
                t0 = time.perf_counter()
                e0, hi, p, fails = [], [], [], 0
                for seed in range(1, a.seeds + 1):
                    c = refinement_check(model, m, eng, seed)
                    e0.append(c.values["e0"])
                    hi.append(c.values["e0_interval"][1])
                    p.append(c.values["order"])
                    fails += c.status != "pass"
                dt = (time.perf_counter() - t0) / a.seeds
                print(f"{label} {model}: clean at {a.seeds} seeds: {fails} false failures; E0 "
                      f"median {np.median(e0):.2g}, max {max(e0):.2g}; interval's upper end max "
                      f"{max(hi):.2g}; order {min(p):.3f}-{max(p):.3f}; {dt:.1f} s a check",
                      flush=True)  # fmt: skip
                for kind in a.faults.split(","):
                    flagged = []
                    for size in (float(s) for s in a.sizes.split(",")):
                        f = make_fault(kind, size)
                        if f.not_applicable(eng) or model not in f.models:
                            continue
                        c = refinement_check(model, m, eng, 1, backend=f.backend(eng.rollout()))
                        print(
                            f"  {kind} {size:g}: E0 {c.values['e0']:.2g} "
                            f"[{c.values['e0_interval'][0]:.2g}, "
                            f"{c.values['e0_interval'][1]:.2g}] -> {c.status}",
                            flush=True,
                        )
                        if c.status == "fail":
                            flagged.append(size)
                    smallest = f"{min(flagged):g}" if flagged else "none"
                    print(f"  {kind}: smallest flagged {smallest}", flush=True)


if __name__ == "__main__":
    main()
