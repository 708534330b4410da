"""Cross-engine validation: every registered engine through the same pipeline.

Each rigid-body engine of :mod:`cipcore.registry` goes through the agreement
stages of ``cip-validate run --engine NAME`` (:mod:`validation.checks.agreement`, the
same profiles, gains, checks and tolerances): lambda1 at the profile's gains,
the time-series agreement with the reduced model (paper eqs. (3) and (5)) and
the direct checks (the engine against its own exact twin, the rod, the delay
measured from its response, the declared model), and the amplitude scan.  An
engine that is not a rigid body (the reduced reference and its GPU kernel) is
held to its declared trajectory tolerance against the reference under the same
noise and to the reference's lambda1.  Beside the checks each row reports the
throughput (realisation-steps/s of the coupled model on a fixed batch, after a
warm-up call), its ratio to MuJoCo on the CPU measured in the same run, and
the linearisation residual where the engine can linearise
(max |A_full - A_reduced - predicted extra terms|, 1/s^2).

An engine that is not installed or needs an absent device is listed as skipped
with the reason; one that raises or whose process dies is listed as crashed with
the reason, and the other engines go on.  The verdict of an engine is the worst
of its checks.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from cipcore.atomic import write_text, write_with
from cipcore.models import MODEL_NAMES
from cipcore.params import BalanceParams, ParameterError
from cipcore.registry import REFERENCE, availability, check_engine_name, engine_names, get_engine
from validation.checks import agreement
from validation.checks.metrics import relative_l2
from validation.checks.stats import FAIL, INCONCLUSIVE, PASS, Check, ci_overlap, worst
from validation.profiles import PAPER_BETA, PROFILES, TRAJECTORY_WINDOW, Profile

#: The engine every throughput is divided by.
SPEED_BASELINE = "mujoco"
#: Largest linearisation residual (1/s^2) of an engine that linearises.
LINEARIZATION_TOLERANCE = 1e-6
#: An engine's status when it raised or its process died: its row keeps what was measured
#: before, ``reason`` says why, and the command exits 4 after writing every other row.
CRASHED = "crashed"
#: An engine's status when the command was interrupted before its checks finished.
INTERRUPTED = "interrupted"
#: Throughput batch (realisations) and duration (s) per profile name (default: quick's).
THROUGHPUT = {"smoke": (8, 0.2), "quick": (64, 1.0), "paper": (256, 2.0)}


def _reference_checks(engine, name: str, profile: Profile, threads: int | None) -> list[Check]:
    """A non-rigid engine against the reference: trajectory within its declared
    tolerance at small amplitude, and lambda1 at the profile's gains."""
    ref = get_engine(REFERENCE)
    checks = []
    caps = engine.capabilities
    for model in MODEL_NAMES:
        p = BalanceParams(beta=PAPER_BETA[model])
        seed = profile.seed_for("series", model)
        args = (model, p, TRAJECTORY_WINDOW, profile.series_realizations, seed)
        kw = {"amplitude": agreement.TWIN_AMPLITUDE, "threads": threads}
        e = engine.simulate(*args, **kw)["balancing_error"]
        r = ref.simulate(*args, **kw)["balancing_error"]
        d = relative_l2(e, r) if np.all(np.isfinite(e)) else float("inf")
        checks.append(Check(
            name=f"engine.trajectory.{model}", status=PASS if d <= caps.trajectory_tolerance
            else FAIL, values={"relative_l2": d},
            tolerance=f"relative L2 distance to the reference <= {caps.trajectory_tolerance:g} "
            "(the engine's declared trajectory_tolerance)",
            details=f"{profile.series_realizations} x {TRAJECTORY_WINDOW:g} s, seed {seed}",
        ))  # fmt: skip
        if name == REFERENCE:
            continue
        for beta in profile.lyapunov_gains[model]:
            pb = BalanceParams(beta=beta)
            seed = profile.seed_for("lyapunov", model, beta)
            la = (model, pb, profile.lyapunov_duration, profile.lyapunov_realizations, seed)
            a, b = engine.lyapunov(*la, threads=threads), ref.lyapunov(*la, threads=threads)
            status, v = ci_overlap(a.lambda1, a.ci95, b.lambda1, b.ci95)
            checks.append(Check(
                name=f"agreement.lambda1.{model}.beta={beta:g}", status=status,
                values={"engine": {"value": a.lambda1, "ci95": list(a.ci95)},
                        "reduced": {"value": b.lambda1, "ci95": list(b.ci95)}, **v},
                tolerance="95% CIs overlap", details=f"seed {seed}",
            ))  # fmt: skip
    return checks


def _throughput(engine, profile: Profile, seed: int, threads: int | None) -> dict:
    n, duration = THROUGHPUT.get(profile.name, THROUGHPUT["quick"])
    p = BalanceParams(beta=PAPER_BETA["coupled"])
    kw = dict(amplitude=1e-3, threads=threads, fields=("balancing_error",))
    t0 = time.perf_counter()
    engine.simulate("coupled", p, 0.2, n, seed, **kw)
    first = time.perf_counter() - t0
    t0 = time.perf_counter()
    engine.simulate("coupled", p, duration, n, seed, **kw)
    wall = time.perf_counter() - t0
    steps = round(duration / p.dt) * n
    return {"realization_steps_per_s": steps / wall, "wall_s": wall, "first_call_s": first,
            "realizations": n}  # fmt: skip


def _value(checks: list[Check], name: str, key: str) -> Any:
    for c in checks:
        if c.name == name:
            return c.values.get(key)
    return None


def _joined(start: dict[str, Any], checks: dict[str, Any]) -> dict[str, Any]:
    """An engine's row: :func:`engine_throughput`'s fields, then :func:`engine_checks`'s."""
    stages = {**start["stage_seconds"], **checks["stage_seconds"]}
    return {**start, **checks, "stage_seconds": stages}


def _skipped(name: str, reason: str) -> dict[str, Any]:
    return {"engine": name, "status": "skipped", "reason": reason}


def engine_throughput(name: str, profile: Profile, threads: int | None) -> dict[str, Any]:
    """The start of an engine's row: its capabilities and its throughput (the engine's
    first call, compilation included, then a timed call: :data:`THROUGHPUT`)."""
    engine = get_engine(name)
    t = time.perf_counter()
    tp = _throughput(engine, profile, profile.seed, threads)
    return {"engine": name, "capabilities": engine.capabilities.as_dict(), "throughput": tp,
            "stage_seconds": {"throughput": round(time.perf_counter() - t, 1)}}  # fmt: skip


def engine_checks(
    name: str, profile: Profile, threads: int | None = None, integrator: str | None = None,
    selftest: bool = False,
) -> dict[str, Any]:  # fmt: skip
    """The checks of one available engine as fields of its row: ``checks``, ``failed``,
    ``status`` and ``stage_seconds`` (wall seconds per stage), and the distances, tiers and
    tolerances read from the checks.

    The function is long because it runs the agreement stages in order and keeps every
    finished stage when an engine fails.
    """
    engine = get_engine(name)
    caps = engine.capabilities
    row: dict[str, Any] = {}
    stages: dict[str, float] = {}  # wall seconds per stage, in the report

    def timed(stage: str, fn, *args, **kwargs):
        t = time.perf_counter()
        out = fn(*args, **kwargs)
        stages[stage] = round(time.perf_counter() - t, 1)
        return out

    row["stage_seconds"] = stages
    if caps.rigid_body:
        target = {"engine": name, "integrator": integrator}
        checks = timed("lambda1", agreement.lyapunov_checks, profile, threads, **target)[0]
        checks += timed("time series", agreement.series_checks, profile, threads, **target)[0]
        checks += timed("amplitude scan", agreement.amplitude_scan, profile, threads, **target)[0]
        row.update(twin_tolerance={m: engine.twin_tolerance_for(m) for m in MODEL_NAMES},
                   rod_tolerance=engine.rod_tolerance,
                   integrator=integrator)  # fmt: skip
        row["twin_distance"] = {
            m: _value(checks, f"twin.trajectory.{m}", "relative_l2") for m in MODEL_NAMES
        }
        row["trajectory_distance"] = {
            m: _value(checks, f"agreement.trajectory.{m}", "relative_l2") for m in MODEL_NAMES
        }
        row["delay_steps"] = {
            m: _value(checks, f"delay.{m}", "measured_steps") for m in MODEL_NAMES
        }
        refined = agreement.judged_by_refinement(checks)
        row["tier"] = {m: "refinement" if m in refined else "exact twin" for m in MODEL_NAMES}
        row["refinement"] = {
            m: {k: _value(checks, f"refinement.{m}", k) for k in ("e0", "order", "floor")}
            for m in MODEL_NAMES
        }
        row["rod_stretch"] = _value(checks, "twin.rod.coupled", "stretch_relative_l2")
        row["rod_stretch_over_error"] = _value(
            checks, "twin.rod.coupled", "stretch_over_balancing_error"
        )
        if selftest:
            from validation.faults.selftest import run_selftest

            clean, faults = timed("selftest", run_selftest, 1, 2, engine=name,
                                  integrator=integrator)  # fmt: skip
            ran = [f for f in faults if f["flagged"] is not None]
            row["selftest"] = {"clean_failures": clean, "flagged": sum(f["flagged"] for f in ran),
                               "applicable": len(ran), "faults": faults}  # fmt: skip
            checks.append(Check(
                name="selftest.faults_flagged",
                status=PASS if not clean and all(f["flagged"] for f in ran) else FAIL,
                values={"flagged": row["selftest"]["flagged"], "applicable": len(ran),
                        "missed": [f["fault"] for f in ran if not f["flagged"]]},
                tolerance="the unmodified engine passes its direct checks and every applicable "
                "catalogued fault fails one", details="seed 1, 2 realisations",
            ))  # fmt: skip
    else:
        checks = _reference_checks(engine, name, profile, threads)
        row["trajectory_distance"] = {
            m: _value(checks, f"engine.trajectory.{m}", "relative_l2") for m in MODEL_NAMES
        }
    if caps.linearize:
        residuals = {m: engine.linearize(m).residual for m in MODEL_NAMES}
        row["linearization_residual"] = residuals
        ok = max(residuals.values()) < LINEARIZATION_TOLERANCE
        checks.append(Check(
            name="engine.linearization", status=PASS if ok else FAIL, values=residuals,
            tolerance=f"max |A_full - A_reduced - predicted extra terms| < "
            f"{LINEARIZATION_TOLERANCE:g} 1/s^2", details="about upright",
        ))  # fmt: skip
    row["checks"] = [c.as_dict() for c in checks]
    row["failed"] = [c.name for c in checks if c.status == FAIL]
    row["status"] = worst([c.status for c in checks])
    return row


def _step_cost(row: dict[str, Any]) -> float:
    """Seconds per step of one realisation as the checks run it, from the throughput: a
    batch engine (``Capabilities.batch``) steps all of a call's realisations in the time
    of one, so a realisation costs it the throughput batch's step."""
    tp = row["throughput"]
    per = tp["realizations"] if row["capabilities"]["batch"] else 1
    return per / tp["realization_steps_per_s"]


def _profile(profile: Profile | str, seed: int | None) -> Profile:
    if isinstance(profile, str):
        if profile not in PROFILES:
            raise ParameterError(f"profile must be one of {', '.join(PROFILES)}, got {profile!r}")
        profile = PROFILES[profile]
    return profile if seed is None else replace(profile, seed=seed)


def parse_engines(text: str | None) -> list[str]:
    """Engine names from "a,b,..." (all registered engines when None or "all")."""
    if text is None or text.strip() == "all":
        return list(engine_names())
    names = [t.strip() for t in text.split(",") if t.strip()]
    if not names:
        raise ParameterError(
            f"engines must be a comma-separated list of {', '.join(engine_names())}"
        )
    return [check_engine_name(n) for n in names]


@dataclass(frozen=True)
class EnginesSetting:
    """How ``cip-validate engines`` checks the engines: one value.

    profile : a profile name (:data:`validation.profiles.PROFILES`).  seed : replaces the
    profile's root seed.  threads : threads per engine (None: all cores, or
    ``cores // jobs`` beside other engines).  jobs : engines checked at a time, each in a
    process of its own.  integrator : MuJoCo's integrator for the engines that follow
    the model file.  selftest : also inject the fault catalogue into each rigid-body
    engine.
    """

    profile: str = "quick"
    seed: int | None = None
    threads: int | None = None
    jobs: int = 1
    integrator: str | None = None
    selftest: bool = False


def compare_engines(
    names: list[str], setting: EnginesSetting = EnginesSetting(), progress: Any = None
) -> dict[str, Any]:
    """One row per engine of ``names`` (:func:`engine_throughput`'s fields, then
    :func:`engine_checks`'s, or why it has no verdict) plus speed ratios to MuJoCo on the
    CPU.  ``setting.selftest`` also injects the fault catalogue at a rigid-body engine's
    boundary (:func:`validation.faults.selftest.run_selftest`, seed 1, 2 realisations) and
    reports how many applicable faults its checks flag.

    Every engine's throughput is measured first, one engine at a time in this process, so
    that no engine is timed beside another; then the checks run ``jobs`` engines at a
    time, each in a process of its own (:func:`validation.engine_jobs.run_side_by_side`),
    the slowest engine first (per step of one realisation: :func:`_step_cost`).  Without
    ``threads``, an engine checked beside others gets ``cores // jobs`` threads.  The
    checks' numbers do not depend on ``jobs``; an engine's ``seconds`` (throughput +
    checks, each timed where it ran) does, and the result states ``jobs``.
    ``progress(line)`` is told each step.
    """
    prof = _profile(setting.profile, setting.seed)
    say = progress or (lambda line: None)
    rows: dict[str, dict[str, Any]] = {}
    workers = 1
    try:
        _throughputs(names, prof, setting.threads, say, rows)
        ran = [n for n in names if rows[n].get("status") is None]
        workers = max(1, min(setting.jobs, len(ran)))
        _checks(ran, prof, setting, workers, say, rows)
        interrupted = False
    except KeyboardInterrupt:
        interrupted = True
    for n in names:  # an engine whose checks did not finish: what was measured, and why
        if rows.get(n, {}).get("status") is None:
            why = "the command was interrupted before its checks finished"
            rows[n] = {**rows.get(n, {"engine": n}), "status": INTERRUPTED, "reason": why}
    ordered = [rows[n] for n in names]
    base = next((r for r in ordered if r["engine"] == SPEED_BASELINE and "throughput" in r), None)
    for r in ordered:
        if base is not None and "throughput" in r:
            r["throughput"]["ratio_to_" + SPEED_BASELINE] = (
                r["throughput"]["realization_steps_per_s"]
                / base["throughput"]["realization_steps_per_s"]
            )
    verdicts = [r["status"] for r in ordered if has_verdict(r)]
    results = {"profile": prof.name, "seed": prof.seed, "engines": ordered,
               "jobs": workers, "status": worst(verdicts) if verdicts else INCONCLUSIVE,
               "crashed": [r["engine"] for r in ordered if r["status"] == CRASHED]}  # fmt: skip
    if interrupted:
        raise EnginesInterrupted({**results, "partial": True})
    return results


class EnginesInterrupted(KeyboardInterrupt):
    """:func:`compare_engines` was interrupted; ``results`` holds every finished engine's
    row and, for the others, what was measured (status :data:`INTERRUPTED`)."""

    def __init__(self, results: dict[str, Any]) -> None:
        super().__init__("interrupted")
        self.results = results


def _throughputs(names: list[str], prof: Profile, threads: int | None, say,
                 rows: dict[str, dict[str, Any]]) -> None:  # fmt: skip
    """Each available engine's throughput, one engine at a time, into ``rows`` (or the
    row that says why not: skipped, crashed)."""
    for n in names:
        reason = availability(n)
        if reason is not None:
            rows[n] = _skipped(n, reason)
            continue
        say(f"engine {n}: throughput")
        try:
            rows[n] = engine_throughput(n, prof, threads)
        except Exception as exc:
            if not _kept(exc):
                raise
            rows[n] = _crashed({"engine": n}, exc)


def _checks(ran: list[str], prof: Profile, setting: EnginesSetting, workers: int, say,
            rows: dict[str, dict[str, Any]]) -> None:  # fmt: skip
    """The checks of the engines ``ran`` (their throughput measured), ``workers`` at a
    time, each finished row into ``rows`` as it arrives."""
    from functools import partial

    from cipcore.driver import default_threads
    from cipcore.registry import registered_at_runtime
    from validation.engine_jobs import EngineJob, run_side_by_side

    threads = setting.threads
    each = threads if threads is not None or workers == 1 else max(1, default_threads() // workers)
    work = partial(engine_checks, profile=prof, threads=each, integrator=setting.integrator,
                   selftest=setting.selftest)  # fmt: skip
    todo = [EngineJob(n, cost=_step_cost(rows[n]), device=rows[n]["capabilities"]["device"],
                      here=registered_at_runtime(n)) for n in ran]  # fmt: skip
    beside = f" ({workers} engines at a time)" if workers > 1 else ""

    def finished(n: str, fields: Any, wall: float) -> None:
        if isinstance(fields, Exception):
            rows[n] = _crashed(rows[n], fields)
            return
        rows[n] = _joined(rows[n], fields)
        rows[n]["seconds"] = round(rows[n]["stage_seconds"]["throughput"] + wall, 1)

    run_side_by_side(todo, work, workers, kept=_kept, finished=finished,
                     started=lambda n: say(f"engine {n}: checks{beside}"))  # fmt: skip


def _kept(error: BaseException) -> bool:
    """An engine's error that becomes its row (:data:`CRASHED`) while the other engines go
    on: any but bad input (:class:`ParameterError`, e.g. an integrator the engine
    refuses), which ends the command."""
    return not isinstance(error, ParameterError)


def _crashed(row: dict[str, Any], error: BaseException) -> dict[str, Any]:
    """``row`` (what was measured before the error) marked :data:`CRASHED` with the reason."""
    return {**row, "status": CRASHED, "reason": f"{type(error).__name__}: {error}"}


def has_verdict(row: dict[str, Any]) -> bool:
    """Whether an engine's row has the verdict of its checks (it was not skipped here, did
    not crash and was not interrupted)."""
    return row["status"] not in ("skipped", CRASHED, INTERRUPTED)


def _g(v: Any, fmt: str = ".3g") -> str:
    if v is None:
        return "n/a"
    if isinstance(v, float) and not np.isfinite(v):
        return str(v)
    return format(v, fmt)


def _rod_cell(row: dict) -> str:
    """The rod's stretch: relative L2 to a soft twin rod's, or RMS over the balancing error's
    RMS for a rigid twin rod (:mod:`validation.checks.rod`)."""
    if row.get("rod_stretch") is not None:
        return _g(row["rod_stretch"])
    if row.get("rod_stretch_over_error") is not None:
        return _g(row["rod_stretch_over_error"]) + " /e"
    return "n/a"


def _tier_cell(row: dict) -> str:
    """Which tier judged the engine per model: T (exact twin) or R (refinement)."""
    tier = row.get("tier")
    if not tier:
        return "n/a"
    return "/".join("T" if tier[m] == "exact twin" else "R" for m in MODEL_NAMES)


def _refinement_cell(row: dict) -> str:
    ref = row.get("refinement") or {}
    if not ref:
        return "n/a"
    floor = next((v["floor"] for v in ref.values() if v.get("floor") is not None), None)
    return " / ".join(_g(ref[m].get("e0"), ".2g") for m in MODEL_NAMES) + f" ({_g(floor, 'g')})"


def _order_cell(row: dict) -> str:
    ref = row.get("refinement") or {}
    return " / ".join(_g(ref[m].get("order"), ".2f") for m in MODEL_NAMES) if ref else "n/a"


def _selftest_cell(st: dict | None) -> str:
    return "not run" if st is None else f"{st['flagged']} of {st['applicable']}"


def _run_line(run: dict[str, Any]) -> str:
    """One sentence: the command that made the results, when, how long, at what load."""
    loads = [("at the start", run.get("load_start")), ("at the end", run.get("load_end"))]
    said = [f"{'/'.join(f'{x:.1f}' for x in v)} {when}" for when, v in loads if v]
    text = f"Made by `{run['command']}` on {run['started_utc']} UTC ({run.get('cpus')} CPUs"
    if said:
        text += ", load " + " and ".join(said)
    if "wall_s" in run:
        text += f"; {run['wall_s'] / 60:.1f} min wall"
    if run.get("commit"):
        text += f"; commit {run['commit']}"
    versions = run.get("versions") or {}
    if versions:
        text += "; " + ", ".join(f"{k} {v}" for k, v in versions.items())
    return text + ")."


def _jobs_line(jobs: int) -> str:
    return (f"The throughputs were measured one engine at a time; the checks ran {jobs} "
            "engines at a time, each in a process of its own, so an engine's time below was "
            "measured beside the others (its checks' numbers do not depend on it).")  # fmt: skip


def markdown(results: dict[str, Any]) -> str:
    """The cross-engine table (one row per engine) and each engine's failed checks."""
    lines = [
        "# Every engine through the same checks",
        "",
        f"Profile {results['profile']}, seed {results['seed']}; every engine sees the reduced "
        "model's noise draws. Twin distance: relative L2 of the balancing error to the "
        "engine's own exact twin at 1e-6 m (tolerance from its measured floor); reduced "
        "distance: to the paper's reduced model at the profile's series amplitude; throughput: "
        "coupled model, realisation-steps/s after a warm-up call. Tier: T, the engine is "
        "judged by its exact twin; R, by time-step refinement against the exact "
        "zero-order-hold solution (validation.checks.refinement: E0, the relative distance of "
        "the dt -> 0 limit, within the floor; the observed order at least the declared one).",
        "",
        *([_run_line(results["run"]), ""] if results.get("run") else []),
        *([_jobs_line(results["jobs"]), ""] if results.get("jobs", 1) > 1 else []),
        "| engine | verdict | family | precision | integrator | rod | tier (single/coupled) "
        "| refinement E0 single / coupled (floor) | observed order | twin distance single "
        "| twin distance coupled | twin tolerance | rod stretch (vs twin or /e) | delay (steps) "
        "| reduced distance coupled | faults flagged | failed checks | steps/s "
        "| ratio to MuJoCo CPU |",
        "|" + "---|" * 19,
    ]
    for r in results["engines"]:
        if not has_verdict(r):
            lines.append(f"| {r['engine']} | {r['status']} | " + " | ".join(["n/a"] * 16)
                         + f" | {r['status']}: {r['reason'].replace('|', '/')} |")  # fmt: skip
            continue
        c = r["capabilities"]
        tw = r.get("twin_distance") or {}
        delay = r.get("delay_steps") or {}
        tp = r["throughput"]
        integ = r.get("integrator") or c.get("integrator", "n/a")
        lines.append(
            f"| {r['engine']} | {r['status']} | {c['family']} | {c['precision']} | {integ} "
            f"| {c.get('rod', 'n/a') if c['rigid_body'] else 'n/a'} "
            f"| {_tier_cell(r)} | {_refinement_cell(r)} | {_order_cell(r)} "
            f"| {_g(tw.get('single'))} | {_g(tw.get('coupled'))} "
            f"| {'/'.join(_g(v) for v in (r.get('twin_tolerance') or {}).values()) or 'n/a'} "
            f"| {_rod_cell(r)} "
            f"| {'/'.join(str(delay[m]) for m in MODEL_NAMES) if delay else 'n/a'} "
            f"| {_g(r['trajectory_distance'].get('coupled'))} "
            f"| {_selftest_cell(r.get('selftest'))} | {len(r['failed'])} "
            f"| {_g(tp['realization_steps_per_s'], '.3e')} "
            f"| {_g(tp.get('ratio_to_' + SPEED_BASELINE))} |"
        )
    lines += reproduced_table(results)
    for r in results["engines"]:
        if not has_verdict(r):
            continue
        c = r["capabilities"]
        lines += ["", f"## {r['engine']}", ""]
        if c.get("twin"):
            lines.append(f"Exact twin: {c['twin']}.")
        if c.get("solver"):
            lines.append(f"Constraint solve (declared, not the model file's): {c['solver']}.")
        if c["rigid_body"] and not c.get("twin"):
            lines.append(f"No exact twin declared: held to the declared twin tolerance "
                         f"{r.get('twin_tolerance')}.")  # fmt: skip
        failed = r["failed"]
        lines.append(("Failed checks: " + ", ".join(failed)) if failed else "Every check passed.")
        tp = r["throughput"]
        lines.append(f"First call (compilation included) {tp['first_call_s']:.2f} s; timed call "
                     f"{tp['wall_s']:.2f} s for {tp['realizations']} realisations; all checks "
                     f"{r['seconds']:.0f} s.")  # fmt: skip
        if r.get("stage_seconds"):
            lines.append("Wall time by stage: " + ", ".join(
                f"{k} {v:.0f} s" for k, v in r["stage_seconds"].items()) + ".")  # fmt: skip
    return "\n".join(lines) + "\n"


def _check(row: dict, name: str) -> dict | None:
    return next((c for c in row.get("checks", []) if c["name"] == name), None)


def reproduced_table(results: dict[str, Any]) -> list[str]:
    """Markdown lines: what each rigid-body engine reproduced, read from its checks.

    Per engine, lambda1 (1/s) of the engine and of the reduced model on the same noise
    at each gain of the profile (``agreement.lambda1.<model>.beta=<b>``: engine /
    reduced and the check's verdict), and, from the amplitude scan
    (``agreement.small_angle_regime.<model>``), the largest |theta| (rad) reached by the
    run of the largest initial amplitude up to which the engine's trajectory agrees
    with the reduced model (relative L2 < 1%), single and coupled.  beta* is not
    estimated per engine (the paper stages of ``cip-validate run`` estimate it with the
    reduced model).
    """
    rows = [r for r in results["engines"]
            if has_verdict(r) and r["capabilities"].get("rigid_body")]  # fmt: skip
    if not rows:
        return []
    gains = []
    for c in rows[0].get("checks", []):
        if c["name"].startswith("agreement.lambda1."):
            gains.append(c["name"].removeprefix("agreement.lambda1."))
    head = ["engine", *[f"lambda1 {g.replace('.beta=', ', beta ')}" for g in gains],
            *[f"agrees up to angle, {m} (rad)" for m in MODEL_NAMES]]  # fmt: skip
    lines = ["", "## What each engine reproduced", "",
             "lambda1 (1/s): the engine / the reduced model on the same noise draws (its "
             "verdict: 95% intervals overlap); agrees up to angle: the largest pendulum "
             "angle reached in the amplitude scan by a run whose trajectory, and those of "
             "every smaller initial amplitude, agree with the reduced model's (relative L2 "
             "< 1%).", "",
             "| " + " | ".join(head) + " |", "|" + "---|" * len(head)]  # fmt: skip
    for r in rows:
        cells = [r["engine"]]
        for g in gains:
            c = _check(r, f"agreement.lambda1.{g}")
            if c is None:
                cells.append("n/a")
                continue
            v = c["values"]
            cells.append(f"{_g(v['full']['value'], '.3f')} / {_g(v['reduced']['value'], '.3f')}"
                         f" ({c['status']})")  # fmt: skip
        for m in MODEL_NAMES:
            c = _check(r, f"agreement.small_angle_regime.{m}")
            angle = (
                (c["values"].get("largest_agreeing_angle") or {}).get("trajectory") if c else None
            )
            cells.append(_g(angle))
        lines.append("| " + " | ".join(cells) + " |")
    return lines


def speed_accuracy_figure(results: dict[str, Any], path: Path) -> Path | None:
    """Throughput against trajectory distance (coupled), one point per engine, log-log."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    pts = [r for r in results["engines"]
           if has_verdict(r) and r["engine"] != REFERENCE]  # fmt: skip
    if not pts:
        return None
    fig, ax = plt.subplots(figsize=(5.5, 4))
    for r in pts:
        x = r["throughput"]["realization_steps_per_s"]
        y = (r.get("twin_distance") or r["trajectory_distance"])["coupled"]
        ax.loglog([x], [y], "o")
        ax.annotate(r["engine"], (x, y), textcoords="offset points", xytext=(5, 5))
    ax.set_xlabel("throughput (realisation-steps/s, coupled)")
    ax.set_ylabel("distance to its exact twin (or the reference) at 1e-6 m")
    ax.set_title("speed against accuracy")
    fig.tight_layout()
    write_with(path, lambda tmp: fig.savefig(tmp, dpi=120, format=Path(path).suffix[1:]))
    plt.close(fig)
    return path


def write_engine_reports(results: dict[str, Any], out_dir: Path, figures: bool = True) -> None:
    """results.json, report.md and a self-contained report.html in ``out_dir``."""
    from validation.report.document import html_report, write_json

    out_dir.mkdir(parents=True, exist_ok=True)
    write_json(results, out_dir / "results.json")
    md = markdown(results)
    if figures and speed_accuracy_figure(results, out_dir / "speed_accuracy.png"):
        md += ("\n![speed against accuracy](speed_accuracy.png)\n\n*Figure 1.* Throughput "
               "(realisation-steps/s, coupled model, after a warm-up call) against the "
               "trajectory distance to the reduced model (relative L2 of the balancing error at "
               f"1e-6 m, coupled), one point per engine that ran; profile {results['profile']}, "
               f"seed {results['seed']}. No figure of the paper.\n")  # fmt: skip
    write_text(out_dir / "report.md", md)
    write_text(out_dir / "report.html", html_report(md, out_dir))
