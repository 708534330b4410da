"""The refinement tier's floor and power: E0 of correct engines over seeds, and faults.

For each engine of the registry that is installed (and MuJoCo with each of its
integrators), runs :func:`validation.checks.refinement.refinement_check` on both
shipped models at ``--seeds`` seeds (the false-failure count of a correct engine),
then, at one seed, the engine with each fault of ``--faults`` at the sizes of
``--sizes`` (relative) injected at its boundary: the smallest flagged size per fault.

    python benchmarks/refinement_power.py [--engines mujoco,drake] [--seeds 20]
        [--faults mass_ratio,pendulum_length,gravity,tip_damping,cart_damping]
        [--sizes 1e-3,1e-4,1e-5,1e-6]

With ``--closed-loop``, the same table for the closed-loop check
(:func:`validation.checks.closed_loop.closed_loop_check`: the engine under cipval's
delayed random-gain controller, at the engine's own precision setting, float32 or
float64) instead of the open-loop one, the clean rows and each fault at ``--fault-seeds``
seeds (flagged when every seed fails):

    python benchmarks/refinement_power.py --closed-loop --engines physx
        --faults tip_damping,cart_damping --sizes 1e-3,3e-4,1e-4 --seeds 5 --fault-seeds 3

With ``--float32``, the float32 table instead (the float32 setting of
:data:`validation.checks.refinement.FLOAT32_SETTINGS`): for each engine of
``--engines`` (``mujoco-float32`` is the float32 stand-in,
:func:`validation.checks.refinement.float32_stand_in`; a float64 engine's rows are the
linearisation's own error), each model and each response amplitude of
``--amplitudes`` (m; the model's float32 window), E0, the interval's upper end and the
observed order of the correct engine at ``--seeds`` seeds and the count that fails the
model's float32 floor; then each fault at each size at ``--fault-seeds`` seeds (E0
range, the least upper end, flagged count), and per fault the smallest size flagged at
every seed, at the setting's amplitude:

    python benchmarks/refinement_power.py --float32 --engines mujoco-float32,physx,mujoco
        [--amplitudes 1e-5,1e-4,1e-3,3e-3,1e-2] [--sizes 1e-3,1e-4] [--fault-seeds 20]
        [--fault-amplitudes setting]
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
    ap.add_argument("--float32", action="store_true", help="the float32 table (docstring)")
    ap.add_argument("--amplitudes", default="1e-5,1e-4,1e-3,3e-3,1e-2",
                    help="--float32: the response amplitudes (m)")  # fmt: skip
    ap.add_argument("--fault-seeds", type=int, default=20, help="--float32: seeds per fault")
    ap.add_argument("--fault-amplitudes", default="setting",
                    help="--float32: amplitudes (m) of the fault rows, or 'setting'")  # fmt: skip
    ap.add_argument("--closed-loop", action="store_true",
                    help="the closed-loop check's table (docstring)")  # fmt: skip
    a = ap.parse_args()
    if a.closed_loop:
        closed_loop_table(a)
        return
    if a.float32:
        float32_table(a)
        return
    from cipcore.registry import get_engine
    from validation.checks.agreement import model_file
    from validation.checks.refinement import refinement_check

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
                for kind, sized in _faults(a, eng, model):
                    flagged = []
                    for size, f in sized:
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


def closed_loop_table(a: argparse.Namespace) -> None:
    """The ``--closed-loop`` table (module docstring): clean at ``--seeds`` seeds, then
    each fault and size at ``--fault-seeds`` seeds, and the smallest size flagged at every
    seed."""
    from cipcore.params import BalanceParams
    from validation.checks.agreement import model_file
    from validation.checks.closed_loop import closed_loop_check
    from validation.profiles import PAPER_BETA

    for name, eng, model in _engine_models(a):
        m = model_file(model)
        p = BalanceParams(beta=PAPER_BETA[model])
        t0 = time.perf_counter()
        cs = [closed_loop_check(model, m, eng, s, params=p) for s in range(1, a.seeds + 1)]
        e0 = [c.values["e0"] for c in cs]
        hi = [c.values["e0_interval"][1] for c in cs]
        fails = sum(c.status != "pass" for c in cs)
        print(f"{name} {model}: clean at {a.seeds} seeds: {fails} false failures; E0 median "
              f"{np.median(e0):.2g}, max {max(e0):.2g}; upper end max {max(hi):.2g}; floor "
              f"{cs[0].values['floor']:g}; {(time.perf_counter() - t0) / a.seeds:.1f} s a "
              "check", flush=True)  # fmt: skip
        for kind, sized in _faults(a, eng, model):
            flagged = []
            for size, f in sized:
                fc = [closed_loop_check(model, m, eng, s, params=p, fault=f)
                      for s in range(1, a.fault_seeds + 1)]  # fmt: skip
                n_fail = sum(c.status == "fail" for c in fc)
                lo = min(c.values["e0"] for c in fc)
                up = min(c.values["e0_interval"][0] for c in fc)
                print(f"  {kind} {size:g}: E0 >= {lo:.2g}, interval's lower end >= {up:.2g}; "
                      f"{n_fail} of {a.fault_seeds} seeds fail", flush=True)  # fmt: skip
                if n_fail == a.fault_seeds:
                    flagged.append(size)
            smallest = f"{min(flagged):g}" if flagged else "none"
            print(f"  {kind}: smallest flagged at every seed {smallest}", flush=True)


def _faults(a: argparse.Namespace, eng, model: str):
    """(kind, [(size, fault), ...]) for each fault of ``--faults``: its sizes of
    ``--sizes`` that apply to the engine and model (``--faults ''``: none, the clean
    rows only)."""
    from validation.faults.catalogue import make_fault

    for kind in filter(None, a.faults.split(",")):
        faults = [(size, make_fault(kind, size)) for size in map(float, a.sizes.split(","))]
        yield kind, [(z, f) for z, f in faults if not f.not_applicable(eng) and model in f.models]


def _engine_models(a: argparse.Namespace):
    """(engine name, engine, model) for each engine of ``--engines`` that can run here and
    each model of ``--models``, after a line with the load."""
    print(f"# load {' '.join(f'{x:.2f}' for x in os.getloadavg())}", flush=True)
    for name in a.engines.split(","):
        eng = _engine(name)
        if eng is not None:
            for model in a.models.split(","):
                yield name, eng, model


#: float32 engines not (yet) in the registry, by name: the module holding ``ENGINE``
UNREGISTERED = {"physx": "cip.engines.physx", "newton": "cip.engines.newton"}


def _engine(name: str):
    """The engine ``name``: the float32 stand-in, a registered engine or one of
    :data:`UNREGISTERED`; None (with a line saying why) where it cannot run here."""
    import importlib

    from cipcore.params import ParameterError
    from cipcore.registry import get_engine
    from validation.checks.refinement import float32_stand_in

    if name == "mujoco-float32":
        return float32_stand_in()
    try:
        eng = get_engine(name)
    except ParameterError as e:
        if name not in UNREGISTERED:
            print(f"{name}: skipped ({e})")
            return None
        eng = importlib.import_module(UNREGISTERED[name]).ENGINE
    why = eng.unavailable()
    if why:
        print(f"{name}: skipped ({why})")
        return None
    return eng


def _runs(model, m, eng, backend, amplitude: float, window: float, seeds: int):
    """(E0, interval's upper end, order, passes the model's float32 setting) per seed."""
    from validation.checks.refinement import (
        FLOAT32_SETTINGS,
        RefinementSetting,
        least_order,
        refine,
    )

    rod = "soft" if eng.capabilities.rod == "soft" else "rigid"
    need = least_order(eng.capabilities)
    out = []
    for seed in range(1, seeds + 1):
        setting = RefinementSetting(seed, window=window, amplitude=amplitude)
        r = refine(m, backend, rod=rod, setting=setting)
        out.append((r.e0, r.e0_interval[1], r.order, r.passes(FLOAT32_SETTINGS[model].floor, need)))
    return out


def float32_table(a: argparse.Namespace) -> None:
    """The ``--float32`` table (module docstring): is long because it prints three tables
    (clean by amplitude, faults by size, the smallest flagged size) in one pass."""
    from validation.checks.agreement import model_file
    from validation.checks.refinement import FLOAT32_SETTINGS

    for name, eng, model in _engine_models(a):
        s = FLOAT32_SETTINGS[model]
        m = model_file(model)
        print(f"{name} {model}: float32 setting |e| {s.amplitude:g} m, {s.window:g} s, floor "
              f"{s.floor:g}", flush=True)  # fmt: skip
        for amp in (float(x) for x in a.amplitudes.split(",")):
            t0 = time.perf_counter()
            r = np.array(_runs(model, m, eng, eng.rollout(), amp, s.window, a.seeds))
            dt = (time.perf_counter() - t0) / a.seeds
            print(f"  clean |e| {amp:g} m: E0 median {np.median(r[:, 0]):.2g}, max "
                  f"{r[:, 0].max():.2g}; upper end max {r[:, 1].max():.2g}; order "
                  f"{r[:, 2].min():.3f}-{r[:, 2].max():.3f}; {int((r[:, 3] == 0).sum())}/"
                  f"{a.seeds} fail the floor; {dt:.1f} s a run", flush=True)  # fmt: skip
        amps = [s.amplitude] if a.fault_amplitudes == "setting" else [
            float(x) for x in a.fault_amplitudes.split(",")]  # fmt: skip
        for amp in amps:
            for kind, sized in _faults(a, eng, model):
                flagged = []
                for size, f in sized:
                    r = np.array(_runs(model, m, eng, f.backend(eng.rollout()), amp, s.window,
                                       a.fault_seeds))  # fmt: skip
                    n_flag = int((r[:, 3] == 0).sum())
                    print(f"  {kind} {size:g} at |e| {amp:g} m: E0 {r[:, 0].min():.2g}-"
                          f"{r[:, 0].max():.2g}, upper end min {r[:, 1].min():.2g}; flagged "
                          f"{n_flag}/{a.fault_seeds}", flush=True)  # fmt: skip
                    if n_flag == a.fault_seeds:
                        flagged.append(size)
                smallest = f"{min(flagged):g}" if flagged else "none"
                print(f"  {kind} at |e| {amp:g} m: smallest flagged at every seed {smallest}",
                      flush=True)  # fmt: skip


if __name__ == "__main__":
    main()
