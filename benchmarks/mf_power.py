"""Power of the multifidelity agreement against plain sampling, over seeds.

For each seed (the profile's seed replaced by ``--first-seed + k``), runs the
time-series agreement checks of both shipped models
(:func:`validation.checks.agreement.series_model_checks`, the engine's exact twin), or
with ``--stage lambda1`` the lambda1 checks at every gain of the profile
(:func:`validation.checks.agreement.lyapunov_checks`), twice at the same profile:
plainly (every model on ``series_realizations`` / ``lyapunov_realizations``, the
allocation before the quick profile switched multifidelity on) and with the
multifidelity allocation (the engine on ``--mf-engine`` realisations, its twin and
the reduced model on ``--mf-twin``; :mod:`validation.checks.multifidelity`).  Per
check it prints the mean interval half-width of each (the paired checks: the 95 %
half-width of the full - reduced difference; the bands: the widest band's; the
slopes: sigma of the difference, the larger slope's; lambda1: the engine's 95 %
half-width, the reduced model's beside it in ``--json``), their ratio, the number of
seeds at which the check failed or was inconclusive (the engine is correct: every
failure is false), how often the multifidelity allocation fell back to plain
sampling, and the engine steps and wall time of each allocation.  The load average
is printed before and after.

    nice -n 10 python benchmarks/mf_power.py [--profile quick] [--seeds 20]
        [--first-seed 2011] [--mf-engine 3] [--mf-twin 16] [--threads 2] [--stage lambda1]
        [--faults tip_damping,noise_scale --sizes 0.01,0.03 --fault-seeds 3] [--json FILE]

``--faults`` also runs the engine with each fault of the catalogue
(:mod:`validation.faults.catalogue`) at each size (with ``--stage lambda1``, in the
engine's Benettin runs) and prints, per check, at how many of ``--fault-seeds`` seeds each
allocation flagged it (failed).
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import sys
import time
from collections.abc import Iterator
from dataclasses import replace

import numpy as np

from cipcore.params import BalanceParams
from cipcore.scenario import EngineTarget, Scenario


def half_width(check: dict) -> float:
    """The interval a check decides on (module docstring), NaN where it has none."""
    v = check["values"]
    if "half_width_1" in v:  # lambda1: the engine's interval
        return v["half_width_1"]
    if "bands" in v:
        return max(half_width({"values": b}) for b in v["bands"])
    if "slope_low" in v:
        return max(v[k]["sigma"] for k in ("slope_low", "slope_high"))
    lo, hi = v.get("difference_ci95", (np.nan, np.nan))
    return (hi - lo) / 2


def run_once(profile, engine: str, threads: int, stage: str = "series"
             ) -> tuple[list, float, float, int]:  # fmt: skip
    """(check dicts, wall s, CPU s, engine steps) of the series checks of both models, or
    of the lambda1 checks (``stage`` "lambda1")."""
    from validation.checks import agreement
    from validation.profiles import PAPER_BETA

    checks, steps, t0, c0 = [], 0, time.perf_counter(), time.process_time()
    if stage == "lambda1":
        got, data = agreement.lyapunov_checks(profile, threads, engine=engine)
        for row in data["lyapunov"]:
            full = row["full"]
            steps += full["n_realizations"] * round(full["duration"] / full["params"]["dt"])
        return ([c.as_dict() for c in got], time.perf_counter() - t0,
                time.process_time() - c0, steps)  # fmt: skip
    for model, beta in PAPER_BETA.items():
        scn = Scenario(model, BalanceParams(beta=beta), profile.series_duration,
                       profile.series_realizations, profile.seed_for("series", model),
                       profile.amplitude)  # fmt: skip
        got, data = agreement.series_model_checks(
            scn, EngineTarget(engine), profile, threads=threads, nearest=None, precision="float64"
        )
        checks += [c.as_dict() for c in got if c.name.startswith("agreement.")]
        full = data["full"]
        steps += full.shape[0] * round(profile.series_duration / full.attrs["dt"])
    return checks, time.perf_counter() - t0, time.process_time() - c0, steps


def with_fault(kind: str, size: float):
    """A :func:`validation.checks.agreement.run_full` whose engine carries a fault of the
    catalogue (:func:`validation.faults.catalogue.make_fault`); the twin and reduced
    model stay correct."""
    from cip.mjcf_params import read_mapping
    from validation.checks import agreement
    from validation.faults.catalogue import make_fault

    fault = make_fault(kind, size)

    def run_full(scenario, target, *, decimate, threads):
        eng = agreement.rigid_engine(target.engine)
        m = agreement.model_file(scenario.model, target.files, target.integrator)
        p = fault.engine_params(scenario.params)
        return eng.simulate(scenario.model, p, scenario.duration, scenario.realizations,
                            scenario.seed, physical=read_mapping(m).physical(),
                            fields=(*agreement.SERIES_FIELDS, "angle"), mj_model=m,
                            backend=fault.backend(eng.rollout()), amplitude=scenario.amplitude,
                            decimate=decimate, threads=threads)  # fmt: skip

    return run_full


@contextlib.contextmanager
def fault_injected(kind: str, size: float, stage: str) -> Iterator[None]:
    """The engine carries fault ``kind`` of ``size`` while the block runs: the series'
    engine runs (:func:`with_fault`) or, for ``stage`` "lambda1", every rigid-body engine's
    Benettin runs (the fault's parameters and rollout backend); the twin and the reduced
    model stay correct."""
    from validation.checks import agreement

    if stage != "lambda1":
        real = agreement.run_full
        agreement.run_full = with_fault(kind, size)
        try:
            yield
        finally:
            agreement.run_full = real
        return
    from cip.engines.rigid_body import RigidBodyEngine
    from validation.faults.catalogue import make_fault

    fault, real = make_fault(kind, size), RigidBodyEngine.lyapunov

    def lyapunov(self, model, params, *args, **options):
        return real(self, model, fault.engine_params(params), *args,
                    backend=fault.backend(self.rollout()), **options)  # fmt: skip

    RigidBodyEngine.lyapunov = lyapunov
    try:
        yield
    finally:
        del RigidBodyEngine.lyapunov  # the inherited method again


def fell_back(checks: list, model: str | None = None) -> bool:
    """Whether a multifidelity run sampled plainly (no check carries its numbers), for the
    checks of ``model`` alone (a name part ``single`` / ``coupled``) when given."""
    mine = [c for c in checks if model is None or model in c["name"].split(".")]
    return not any("n_twin" in json.dumps(c["values"]) for c in mine)


def pairs(checks: list, model: str) -> list[int]:
    """The engine realisations paired (``values["n"]``) in each multifidelity check of
    ``model`` (a batch engine pairs every realisation of its one call)."""
    out = []
    for c in checks:
        v = c["values"]
        v = v if "n_twin" in v else v.get("full") or {}  # lambda1: under the engine's "full"
        if model in c["name"].split(".") and "n_twin" in v and "n" in v:
            out.append(int(v["n"]))
    return out


def summarise(rows: dict[str, list[dict]]) -> list[dict]:
    """Per check: mean half-widths, the ratio of the means and the median per-seed ratio
    (both zero: 1), the seeds at which multifidelity's was wider, non-pass counts."""
    out = []
    plain, mf = rows["plain"], rows["mf"]
    for name in [c["name"] for c in plain[0]["checks"]]:
        hp = [half_width(next(c for c in r["checks"] if c["name"] == name)) for r in plain]
        hm = [half_width(next(c for c in r["checks"] if c["name"] == name)) for r in mf]
        sp = [next(c for c in r["checks"] if c["name"] == name)["status"] for r in plain]
        sm = [next(c for c in r["checks"] if c["name"] == name)["status"] for r in mf]
        hp, hm = np.array(hp), np.array(hm)
        both0 = (hp == 0) & (hm == 0)  # an interval of zero width in both: equal
        ratio = np.where(both0, 1.0, hm / np.where(hp > 0, hp, np.nan))
        out.append({"check": name, "half_width_plain": float(np.mean(hp)),
                    "half_width_mf": float(np.mean(hm)),
                    "ratio_of_means": float(np.mean(hm) / np.mean(hp)) if np.mean(hp) > 0
                    else np.nan,
                    "median_ratio": float(np.nanmedian(ratio)) if np.isfinite(ratio).any()
                    else np.nan,
                    "wider_seeds": int(np.sum(hm > hp)),
                    "fail_plain": sp.count("fail"), "fail_mf": sm.count("fail"),
                    "inconclusive_plain": sp.count("inconclusive"),
                    "inconclusive_mf": sm.count("inconclusive")})  # fmt: skip
    return out


def seed_runs(base, a) -> dict[str, list[dict]]:
    """Both allocations at ``a.seeds`` seeds: {"plain": [...], "mf": [...]} rows."""
    rows: dict[str, list[dict]] = {"plain": [], "mf": []}
    for k in range(a.seeds):
        plain = replace(base, seed=a.first_seed + k, mf_engine_realizations=0)
        mf = replace(plain, mf_engine_realizations=a.mf_engine, mf_twin_realizations=a.mf_twin)
        for label, prof in (("plain", plain), ("mf", mf)):
            checks, wall, cpu, steps = run_once(prof, a.engine, a.threads, a.stage)
            rows[label].append({"seed": prof.seed, "checks": checks, "wall_s": wall,
                                "cpu_s": cpu, "engine_steps": steps,
                                "fell_back": fell_back(checks)})  # fmt: skip
            bad = [c["name"] for c in checks if c["status"] != "pass"]
            print(f"seed {prof.seed} {label:5s} {wall:6.1f} s wall {cpu:6.1f} s CPU {steps:9d} "
                  f"engine steps; not passing: {bad or '-'}", flush=True)  # fmt: skip
    return rows


def print_table(base, a, rows: dict[str, list[dict]]) -> list[dict]:
    """The per-check table of :func:`summarise` and the cost lines; returns the table."""
    table = summarise(rows)
    stage = getattr(a, "stage", "series")
    n, duration = ((base.lyapunov_realizations, base.lyapunov_duration) if stage == "lambda1"
                   else (base.series_realizations, base.series_duration))  # fmt: skip
    short = (base.mf_engine_duration or duration) if stage == "lambda1" else duration
    print(f"\nprofile {a.profile}, stage {stage}, engine {a.engine}, {a.seeds} seeds from "
          f"{a.first_seed}; plain {n} x {duration:g} s per check, multifidelity engine "
          f"{a.mf_engine} x {short:g} s + twin and reduced {a.mf_twin} x "
          f"{duration:g} s")  # fmt: skip
    print(f"{'check':38s} {'hw plain':>10s} {'hw mf':>10s} {'mf/plain':>8s} {'median':>7s} "
          f"{'wider':>5s} {'fail p/mf':>9s} {'inc p/mf':>8s}")  # fmt: skip
    for r in table:
        print(f"{r['check']:38s} {r['half_width_plain']:10.3g} {r['half_width_mf']:10.3g} "
              f"{r['ratio_of_means']:8.3f} {r['median_ratio']:7.3f} {r['wider_seeds']:5d} "
              f"{r['fail_plain']:4d}/{r['fail_mf']:<4d} "
              f"{r['inconclusive_plain']:3d}/{r['inconclusive_mf']:<4d}")  # fmt: skip
    for label in ("plain", "mf"):
        rs = rows[label]
        print(f"{label:5s}: engine steps per seed {rs[0]['engine_steps']}, per seed median "
              f"{np.median([r['wall_s'] for r in rs]):.1f} s wall, "
              f"{np.median([r['cpu_s'] for r in rs]):.1f} s CPU", end="")  # fmt: skip
        if label == "plain":
            print()
            continue
        models = ("single", "coupled")
        back = ", ".join(f"{m} {sum(fell_back(r['checks'], m) for r in rs)}" for m in models)
        n = {m: sorted({k for r in rs for k in pairs(r["checks"], m)}) for m in models}
        print(f"; fell back to plain sampling at (of {len(rs)} seeds) {back}; engine "
              f"realisations paired where not: "
              + ", ".join(f"{m} {n[m] or '-'}" for m in models))  # fmt: skip
    return table


def fault_runs(base, a) -> list[dict]:
    """Each fault of ``a.faults`` at each size, ``a.fault_seeds`` seeds, both allocations:
    per fault, size and check, the seeds at which it failed (flagged the fault)."""
    out = []
    stage = getattr(a, "stage", "series")
    for kind in filter(None, a.faults.split(",")):
        for size in (float(x) for x in a.sizes.split(",")):
            flagged: dict[str, list[int]] = {}
            with fault_injected(kind, size, stage):
                for k in range(a.fault_seeds):
                    plain = replace(base, seed=a.first_seed + k, mf_engine_realizations=0)
                    mf = replace(plain, mf_engine_realizations=a.mf_engine,
                                 mf_twin_realizations=a.mf_twin)  # fmt: skip
                    for j, prof in enumerate((plain, mf)):
                        for c in run_once(prof, a.engine, a.threads, stage)[0]:
                            hits = flagged.setdefault(c["name"], [0, 0])
                            hits[j] += c["status"] == "fail"
            for name, (p, m) in flagged.items():
                out.append({"fault": kind, "size": size, "check": name, "fail_plain": p,
                            "fail_mf": m})  # fmt: skip
                if p or m:
                    print(
                        f"fault {kind} {size:g}: {name:38s} flagged at {p}/{a.fault_seeds} "
                        f"seeds plain, {m}/{a.fault_seeds} multifidelity",
                        flush=True,
                    )
    return out


def merged_table(paths: list[str]) -> int:
    """Print the table of several ``--json`` files (the same allocation, other seeds)."""
    from validation.profiles import PROFILES

    docs = [json.loads(open(p).read()) for p in paths]
    args = docs[0]["args"]
    rows = {k: [r for d in docs for r in d["rows"][k]] for k in ("plain", "mf")}
    a = argparse.Namespace(**args)
    a.seeds = len(rows["plain"])
    if a.seeds:
        a.first_seed = min(r["seed"] for r in rows["plain"])
        print_table(PROFILES[a.profile], a, rows)
    for d in docs:
        for f in d["faults"]:
            if f["fail_plain"] or f["fail_mf"]:
                print(f"fault {f['fault']} {f['size']:g}: {f['check']:38s} flagged at "
                      f"{f['fail_plain']}/{d['args']['fault_seeds']} seeds plain, "
                      f"{f['fail_mf']}/{d['args']['fault_seeds']} multifidelity")  # fmt: skip
    return 0


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--profile", default="quick")
    ap.add_argument("--engine", default="mujoco")
    ap.add_argument("--seeds", type=int, default=20)
    ap.add_argument("--first-seed", type=int, default=2011)
    ap.add_argument("--mf-engine", type=int, default=3, help="engine realisations (multifidelity)")
    ap.add_argument("--mf-twin", type=int, default=16, help="twin and reduced realisations")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument(
        "--stage",
        choices=("series", "lambda1"),
        default="series",
        help="the agreement checks compared (--faults: series only)",
    )
    ap.add_argument("--faults", default="", help="catalogue faults in the engine, e.g. tip_damping")
    ap.add_argument("--sizes", default="0.01,0.03", help="relative fault sizes")
    ap.add_argument("--fault-seeds", type=int, default=3)
    ap.add_argument("--json", default=None, help="write every check of every run here")
    ap.add_argument("--from-json", nargs="+", default=None, help="print these --json files' table")
    a = ap.parse_args()
    if a.from_json:
        return merged_table(a.from_json)
    from validation.profiles import PROFILES

    if a.profile not in PROFILES:
        ap.error(f"--profile must be one of {', '.join(PROFILES)}, got {a.profile!r}")
    base = PROFILES[a.profile]
    if not 3 <= a.mf_engine < base.series_realizations:
        ap.error(f"--mf-engine must be in [3, {base.series_realizations}), got {a.mf_engine}")
    if min(a.threads, a.fault_seeds) < 1 or a.seeds < 0 or a.mf_twin < base.series_realizations:
        ap.error(f"--fault-seeds and --threads must be >= 1, --seeds >= 0 and --mf-twin >= "
                 f"{base.series_realizations}")  # fmt: skip
    print("# load average before: {:.2f} {:.2f} {:.2f}".format(*os.getloadavg()), flush=True)
    rows = seed_runs(base, a) if a.seeds else {"plain": [], "mf": []}
    faults = fault_runs(base, a)
    print("# load average after: {:.2f} {:.2f} {:.2f}".format(*os.getloadavg()))
    table = print_table(base, a, rows) if a.seeds else []
    if a.json:
        from cipcore.atomic import write_bytes

        doc = {"rows": rows, "table": table, "faults": faults, "args": vars(a)}
        write_bytes(a.json, json.dumps(doc, default=float).encode())
    return 0


if __name__ == "__main__":
    sys.exit(main())
