"""Throughput of every registered engine, and its ratio to MuJoCo on the CPU, in one run.

For the coupled CIP at the paper's coupled gain, each available engine
simulates R realisations for ``--duration`` s (delayed random-gain control,
noise, recording of the balancing errors) after one warm-up call of the same
shape (compilation is reported separately as "first call").  Prints
realisation-steps/s per engine and batch size, and the ratio to the engine
named by ``--baseline`` measured in the same run.  ``--threads`` takes a list
(``--threads 1,2``): each engine runs at each count, and the speed-up over the first
count is printed (for Drake the threads are worker processes, so ``--engines drake
--threads 1,2`` shows its 1-process against its 2-process speed in one run).  The
load average is printed before and after (a shared machine's numbers mean little
without it); when MJX ran, its compile times (``cip.engines.mjx.COMPILE_LOG``) too.
``--native`` adds, per engine and batch size, the throughput of the engine's own step
call in a tight loop on the same model and realisations, one thread, a control held
(``benchmarks/native_loops.py``, its timed calls alternated with the adapter's), and
the ratio adapter / native; "n/a" and the reason where an engine has no such loop.
``--repeat K`` keeps the fastest of K timed calls (adapter and native alike; default 1).

Usage:  python benchmarks/bench_engines.py [--engines mujoco,mjx] [--realizations 1,16,128]
                                           [--duration 1] [--threads N[,M...]] [--native]
                                           [--repeat K]
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import time
from collections.abc import Callable

from native_loops import NativeCase, NotIsolated, make_case, native_loop

from cipcore.params import BalanceParams
from cipcore.registry import availability, engine_names, get_engine

#: the start's balancing error (m)
AMPLITUDE = 1e-3


def _seconds(eng: object, p: BalanceParams, duration: float, r: int, kw: dict) -> float:
    """Wall-clock seconds of one ``eng.simulate`` of the coupled model."""
    t0 = time.perf_counter()
    eng.simulate("coupled", p, duration, r, 0, **kw)
    return time.perf_counter() - t0


def _native(name: str, eng: object, p: BalanceParams, r: int, steps: int):
    """(engine ``name``'s own loop on the coupled model, its case) after one untimed call
    of it (MJX compiles there) (:mod:`native_loops`), or the reason there is none."""
    try:
        loop = native_loop(name)
        case = make_case(eng, "coupled", p, r, steps, AMPLITUDE)
        loop(case)
        return loop, case
    except NotIsolated as exc:
        return str(exc)
    except Exception as exc:  # a loop that fails is reported in its row, never as a number
        return f"its loop failed: {type(exc).__name__}: {exc}"


def _timed(loop: Callable[[NativeCase], float] | None, case: NativeCase | None) -> float:
    """Seconds of the timed steps of one call of a native loop; inf where there is none."""
    return math.inf if loop is None or case is None else loop(case)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--engines", default=",".join(engine_names()))
    ap.add_argument("--realizations", default="1,16,128")
    ap.add_argument("--duration", type=float, default=1.0, help="simulated s per realisation")
    ap.add_argument("--threads", default=None, help="thread (Drake: process) counts, e.g. 1,2")
    ap.add_argument("--baseline", default="mujoco")
    ap.add_argument("--native", action="store_true", help="also time each engine's own loop")
    ap.add_argument("--repeat", type=int, default=1, help="timed calls; the fastest is kept")
    a = ap.parse_args()
    p = BalanceParams(beta=21.032)
    steps = round(a.duration / p.dt)
    sizes = [int(s) for s in a.realizations.split(",")]
    counts = [int(t) for t in a.threads.split(",")] if a.threads else [None]
    rate: dict[tuple[str, int, int | None], float] = {}
    print("load average before: {:.2f} {:.2f} {:.2f}".format(*os.getloadavg()))
    print(f"coupled CIP, {a.duration:g} s = {steps} steps per realisation")
    native_head = f" {'native/s':>12s} {'x native':>9s}" if a.native else ""
    print(
        f"{'engine':12s} {'threads':>7s} {'R':>7s} {'first call s':>13s} {'steps/s':>12s} "
        f"{'x ' + a.baseline:>12s} {'x threads ' + str(counts[0]):>12s}{native_head}"
    )
    for name in a.engines.split(","):
        why = availability(name)
        if why is not None:
            print(f"{name:12s} skipped: {why}")
            continue
        eng = get_engine(name)
        for r in sizes:
            nat = _native(name, eng, p, r, steps) if a.native else "not asked"
            loop, case = nat if isinstance(nat, tuple) else (None, None)
            native_s = math.inf
            for t in counts:
                kw = dict(amplitude=AMPLITUDE, threads=t, fields=("balancing_error",))
                t0 = time.perf_counter()
                eng.simulate("coupled", p, a.duration, r, 0, **kw)
                first = time.perf_counter() - t0
                best = math.inf
                for _ in range(max(1, a.repeat)):  # adapter and native alternated
                    best = min(best, _seconds(eng, p, a.duration, r, kw))
                    native_s = min(native_s, _timed(loop, case))
                rate[name, r, t] = v = r * steps / best
                base, one = rate.get((a.baseline, r, t)), rate[name, r, counts[0]]
                ratio = f"{v / base:12.3f}" if base else f"{'n/a':>12s}"
                nv = r * steps / native_s
                cells = f" {nv:12.4g} {v / nv:9.3f}" if nv > 0 else f" {'n/a':>12s} {'n/a':>9s}"
                print(f"{name:12s} {t or '-':>7} {r:7d} {first:13.2f} {v:12.4g} {ratio} "
                      f"{v / one:12.3f}{cells if a.native else ''}")  # fmt: skip
            if a.native and not isinstance(nat, tuple):
                print(f"{'':12s} native n/a: {nat}")
    print("load average after:  {:.2f} {:.2f} {:.2f}".format(*os.getloadavg()))
    mjx = sys.modules.get("cip.engines.mjx")
    for c in getattr(mjx, "COMPILE_LOG", []):
        print(f"mjx compiled {c['rows']} rows x {c['steps']} steps in {c['seconds']:.2f} s "
              f"(persistent cache {c['persistent_cache']}, "
              f"exported chunk {c['exported']})")  # fmt: skip


if __name__ == "__main__":
    main()
