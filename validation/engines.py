"""Cross-engine validation: every registered engine against the reduced reference.

For each engine of :mod:`cipcore.registry` the same checks run under the same
noise draws as the reduced model (paper eqs. bormann04:TM and sss08:TM):

* **trajectory distance** at small amplitude (1e-6 m): relative L2 distance of
  the balancing errors, ||e_engine - e_reduced|| / ||e_reduced||, single and
  coupled, against the tolerance the engine declares
  (:attr:`cipcore.engine.Capabilities.trajectory_tolerance`).  For the rigid
  body the distance is dominated by the cart reaction, proportional to m/M
  (about 3e-3 at the default m/M = 1e-3);
* **lambda1** (1/s) at three gains per model, mean and Student-t 95 % CI over
  realisations, against the reduced model's (CI overlap rule of
  :func:`validation.stats.ci_overlap`);
* **amplitude scan**: the trajectory distance at initial balancing errors from
  1e-6 m to 0.1 m, the largest |theta| reached in a run that still agrees
  within 1 % (the breakdown angle of the small-angle regime), and a check that
  the engine *disagrees* far outside it: a rigid body is nonlinear, so its
  distance at the largest amplitude must exceed the small-amplitude distance
  (set by the linear extra terms) by a factor :data:`NONLINEAR_GROWTH`;
* **linearisation residual** where the engine can linearise
  (max |A_full - A_reduced - predicted extra terms|, 1/s^2);
* **rod length held**: largest horizontal distance between the two tips of the
  coupled model relative to the largest balancing error;
* **throughput**: realisation-steps/s of the coupled model on a fixed batch,
  after a warm-up call (compilation reported separately), and its ratio to
  MuJoCo on the CPU measured in the same run.

An engine that is not installed or needs an absent device is listed as skipped
with the reason.  The verdict of an engine is the worst of its checks.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from cipcore.atomic import write_text, write_with
from cipcore.models import MODEL_NAMES
from cipcore.params import BalanceParams, ParameterError
from cipcore.registry import REFERENCE, availability, check_engine_name, engine_names, get_engine

from .metrics import relative_l2
from .profiles import PAPER_BETA
from .stats import FAIL, INCONCLUSIVE, PASS, ci_overlap, worst

#: Relative trajectory distance below which a run "agrees" in the amplitude scan.
SCAN_AGREEMENT = 1e-2
#: A rigid body is nonlinear: at the largest scanned amplitude its distance to the
#: linear reduced model must exceed the small-amplitude distance by this factor.
NONLINEAR_GROWTH = 3.0
#: Rod check: largest tip mismatch relative to the largest balancing error.
ROD_TOLERANCE = 1e-3
#: The engine every throughput is divided by.
SPEED_BASELINE = "mujoco"


@dataclass(frozen=True)
class EngineProfile:
    """Sizes of the cross-engine checks (durations in s)."""

    name: str
    trajectory_duration: float
    trajectory_realizations: int
    lyapunov_gains: dict[str, tuple[float, ...]]
    lyapunov_duration: float
    lyapunov_realizations: int
    scan_amplitudes: tuple[float, ...]
    scan_duration: float
    throughput_realizations: int
    throughput_duration: float


_GAINS = {"single": (19.5, PAPER_BETA["single"], 23.0), "coupled": (20.5, 21.0, 23.0)}

ENGINE_PROFILES: dict[str, EngineProfile] = {
    "smoke": EngineProfile("smoke", 1.0, 2, _GAINS, 5.0, 4, (1e-6, 1e-2, 1e-1), 1.0, 8, 0.2),
    "quick": EngineProfile(
        "quick", 5.0, 4, _GAINS, 30.0, 8, (1e-6, 1e-3, 1e-2, 3e-2, 1e-1), 5.0, 64, 1.0
    ),
    "paper": EngineProfile(
        "paper", 10.0, 8, _GAINS, 500.0, 16, (1e-6, 1e-4, 1e-3, 1e-2, 3e-2, 1e-1), 10.0, 256, 2.0
    ),
}


def _distance(a: np.ndarray, b: np.ndarray) -> float:
    """Relative L2 distance ||a - b|| / ||b|| (inf when a is not finite)."""
    if not np.all(np.isfinite(a)):
        return float("inf")
    return relative_l2(a, b)


def _trajectory(engine, prof: EngineProfile, seed: int, threads: int | None) -> dict:
    out = {}
    ref = get_engine(REFERENCE)
    for model in MODEL_NAMES:
        p = BalanceParams(beta=PAPER_BETA[model])
        kw = dict(amplitude=1e-6, threads=threads)
        e = engine.simulate(model, p, prof.trajectory_duration, prof.trajectory_realizations,
                            seed, **kw)["balancing_error"]  # fmt: skip
        r = ref.simulate(model, p, prof.trajectory_duration, prof.trajectory_realizations,
                         seed, **kw)["balancing_error"]  # fmt: skip
        out[model] = _distance(e, r)
    return out


def _lyapunov(engine, prof: EngineProfile, seed: int, threads: int | None) -> list[dict]:
    ref = get_engine(REFERENCE)
    rows = []
    for model in MODEL_NAMES:
        for beta in prof.lyapunov_gains[model]:
            p = BalanceParams(beta=beta)
            args = (model, p, prof.lyapunov_duration, prof.lyapunov_realizations, seed)
            a = engine.lyapunov(*args, threads=threads)
            b = ref.lyapunov(*args, threads=threads)
            status, detail = ci_overlap(a.lambda1, a.ci95, b.lambda1, b.ci95)
            rows.append({
                "model": model, "beta": beta, "status": status,
                "engine": {"value": a.lambda1, "ci95": list(a.ci95)},
                "reduced": {"value": b.lambda1, "ci95": list(b.ci95)}, **detail,
            })  # fmt: skip
    return rows


def _scan(engine, prof: EngineProfile, seed: int, threads: int | None) -> dict:
    ref = get_engine(REFERENCE)
    p = BalanceParams(beta=PAPER_BETA["coupled"])
    rows = []
    for amp in prof.scan_amplitudes:
        tr = engine.simulate("coupled", p, prof.scan_duration, 2, seed, amplitude=amp,
                             threads=threads)  # fmt: skip
        red = ref.simulate("coupled", p, prof.scan_duration, 2, seed, amplitude=amp,
                           threads=threads)  # fmt: skip
        n = tr["balancing_error"].shape[1]
        dist = _distance(tr["balancing_error"], red["balancing_error"][:, :n])
        angle = tr.data.get("angle")
        max_angle = float(np.nanmax(np.abs(angle))) if angle is not None else float("nan")
        rows.append({"amplitude": amp, "distance": dist, "max_angle": max_angle,
                     "diverged": tr.attrs.get("diverged")})  # fmt: skip
    agreeing = [r for r in rows if r["distance"] <= SCAN_AGREEMENT]
    breakdown = max((r["max_angle"] for r in agreeing), default=float("nan"))
    nonlinear = rows[-1]["distance"] > NONLINEAR_GROWTH * rows[0]["distance"]
    return {"rows": rows, "breakdown_angle": breakdown, "disagrees_far_outside": nonlinear}


def _rod(engine, seed: int, threads: int | None) -> float:
    tr = engine.simulate("coupled", BalanceParams(beta=PAPER_BETA["coupled"]), 2.0, 2, seed,
                         amplitude=1e-3, threads=threads)  # fmt: skip
    tips = tr["tip_position"]
    return float(np.abs(tips[..., 0] - tips[..., 1]).max() / np.abs(tr["balancing_error"]).max())


def _throughput(engine, prof: EngineProfile, seed: int, threads: int | None) -> dict:
    p = BalanceParams(beta=PAPER_BETA["coupled"])
    kw = dict(amplitude=1e-3, threads=threads, fields=("balancing_error",))
    t0 = time.perf_counter()
    engine.simulate("coupled", p, 0.2, prof.throughput_realizations, seed, **kw)
    first = time.perf_counter() - t0
    t0 = time.perf_counter()
    engine.simulate("coupled", p, prof.throughput_duration, prof.throughput_realizations, seed,
                    **kw)  # fmt: skip
    wall = time.perf_counter() - t0
    steps = round(prof.throughput_duration / p.dt) * prof.throughput_realizations
    return {"realization_steps_per_s": steps / wall, "wall_s": wall, "first_call_s": first,
            "realizations": prof.throughput_realizations}  # fmt: skip


def validate_engine(
    name: str, prof: EngineProfile, seed: int = 0, threads: int | None = None
) -> dict[str, Any]:
    """Every cross-engine check of one engine (see the module docstring)."""
    reason = availability(name)
    if reason is not None:
        return {"engine": name, "status": "skipped", "reason": reason}
    engine = get_engine(name)
    caps = engine.capabilities
    row: dict[str, Any] = {"engine": name, "capabilities": caps.as_dict()}
    checks: dict[str, str] = {}
    row["throughput"] = _throughput(engine, prof, seed, threads)
    dist = _trajectory(engine, prof, seed, threads)
    row["trajectory_distance"] = dist
    checks["trajectory"] = (
        PASS if all(d <= caps.trajectory_tolerance for d in dist.values()) else FAIL
    )
    if name != REFERENCE:
        row["lyapunov"] = _lyapunov(engine, prof, seed, threads)
        checks["lyapunov"] = worst([r["status"] for r in row["lyapunov"]])
    if caps.rigid_body:
        row["amplitude_scan"] = _scan(engine, prof, seed, threads)
        checks["nonlinear_far_outside"] = (
            PASS if row["amplitude_scan"]["disagrees_far_outside"] else FAIL
        )
        row["rod_mismatch"] = _rod(engine, seed, threads)
        checks["rod"] = PASS if row["rod_mismatch"] < ROD_TOLERANCE else FAIL
    if caps.linearize:
        residuals = {m: engine.linearize(m).residual for m in MODEL_NAMES}
        row["linearization_residual"] = residuals
        checks["linearization"] = PASS if max(residuals.values()) < 1e-6 else FAIL
    row["checks"] = checks
    row["status"] = worst(list(checks.values()))
    return row


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


def compare_engines(
    names: list[str],
    profile: str = "quick",
    seed: int = 0,
    threads: int | None = None,
    progress: Any = None,
) -> dict[str, Any]:
    """Rows of :func:`validate_engine` for ``names`` plus speed ratios to MuJoCo on the CPU."""
    if profile not in ENGINE_PROFILES:
        raise ParameterError(
            f"profile must be one of {', '.join(ENGINE_PROFILES)}, got {profile!r}"
        )
    prof = ENGINE_PROFILES[profile]
    rows = []
    for n in names:
        if progress:
            progress(n)
        rows.append(validate_engine(n, prof, seed, threads))
    base = next((r for r in rows if r["engine"] == SPEED_BASELINE and "throughput" in r), None)
    for r in rows:
        if base is not None and "throughput" in r:
            r["throughput"]["ratio_to_" + SPEED_BASELINE] = (
                r["throughput"]["realization_steps_per_s"]
                / base["throughput"]["realization_steps_per_s"]
            )
    ran = [r["status"] for r in rows if r["status"] != "skipped"]
    return {"profile": profile, "seed": seed, "engines": rows,
            "status": worst(ran) if ran else INCONCLUSIVE}  # fmt: skip


def _g(v: Any, fmt: str = ".3g") -> str:
    if v is None:
        return "n/a"
    if isinstance(v, float) and not np.isfinite(v):
        return str(v)
    return format(v, fmt)


def markdown(results: dict[str, Any]) -> str:
    """The cross-engine table (one row per engine) and the details per engine."""
    lines = [
        "# Cross-engine validation against the reduced model",
        "",
        f"Profile {results['profile']}, seed {results['seed']}; every engine sees the reduced "
        "model's noise draws. Trajectory distance: relative L2 of the balancing error at "
        "1e-6 m; throughput: coupled model, realisation-steps/s after a warm-up call.",
        "",
        "| engine | verdict | family | precision | device | distance single | distance coupled "
        "| tolerance | lambda1 checks | breakdown angle (rad) | rod mismatch | linearisation "
        "residual (1/s^2) | steps/s | ratio to MuJoCo CPU |",
        "|" + "---|" * 14,
    ]
    for r in results["engines"]:
        if r["status"] == "skipped":
            # 14 cells as the header: engine, verdict, 11 n/a, the reason in the last column
            lines.append(f"| {r['engine']} | skipped | " + " | ".join(["n/a"] * 11)
                         + f" | skipped: {r['reason'].replace('|', '/')} |")  # fmt: skip
            continue
        c = r["capabilities"]
        d = r["trajectory_distance"]
        lyap = r.get("lyapunov")
        lyap_s = (f"{sum(x['status'] == PASS for x in lyap)}/{len(lyap)} pass" if lyap
                  else "reference")  # fmt: skip
        scan = r.get("amplitude_scan", {})
        lin = r.get("linearization_residual")
        tp = r["throughput"]
        lines.append(
            f"| {r['engine']} | {r['status']} | {c['family']} ({c.get('integrator')}, "
            f"rod {c.get('rod')}) | {c['precision']} | {c['device']} "
            f"| {_g(d['single'])} | {_g(d['coupled'])} | {_g(c['trajectory_tolerance'])} "
            f"| {lyap_s} | {_g(scan.get('breakdown_angle'))} | {_g(r.get('rod_mismatch'))} "
            f"| {_g(max(lin.values())) if lin else 'n/a'} "
            f"| {_g(tp['realization_steps_per_s'], '.3e')} "
            f"| {_g(tp.get('ratio_to_' + SPEED_BASELINE))} |"
        )
    for r in results["engines"]:
        if r["status"] == "skipped" or "lyapunov" not in r:
            continue
        lines += [
            "",
            f"## {r['engine']}: lambda1 against the reduced model (1/s, 95 % CI)",
            "",
            "| model | beta | verdict | engine | reduced |",
            "|---|---|---|---|---|",
        ]
        for x in r["lyapunov"]:
            e, red = x["engine"], x["reduced"]
            lines.append(
                f"| {x['model']} | {x['beta']} | {x['status']} | {e['value']:.4f} "
                f"[{e['ci95'][0]:.4f}, {e['ci95'][1]:.4f}] | {red['value']:.4f} "
                f"[{red['ci95'][0]:.4f}, {red['ci95'][1]:.4f}] |"
            )
        if "amplitude_scan" in r:
            lines += [
                "",
                f"## {r['engine']}: amplitude scan (coupled)",
                "",
                "| amplitude (m) | distance | largest abs(theta) (rad) |",
                "|---|---|---|",
            ]
            for x in r["amplitude_scan"]["rows"]:
                lines.append(f"| {x['amplitude']:g} | {_g(x['distance'])} | {_g(x['max_angle'])} |")
        tp = r["throughput"]
        lines += ["", f"First call (compilation included) {tp['first_call_s']:.2f} s; timed call "
                  f"{tp['wall_s']:.2f} s for {tp['realizations']} realisations."]  # fmt: skip
    return "\n".join(lines) + "\n"


def speed_accuracy_figure(results: dict[str, Any], path: Path) -> Path | None:
    """Throughput against trajectory distance (coupled), one point per engine, log-log."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    pts = [r for r in results["engines"]
           if r["status"] != "skipped" and r["engine"] != REFERENCE]  # fmt: skip
    if not pts:
        return None
    fig, ax = plt.subplots(figsize=(5.5, 4))
    for r in pts:
        x = r["throughput"]["realization_steps_per_s"]
        y = r["trajectory_distance"]["coupled"]
        ax.loglog([x], [y], "o")
        ax.annotate(r["engine"], (x, y), textcoords="offset points", xytext=(5, 5))
    ax.set_xlabel("throughput (realisation-steps/s, coupled)")
    ax.set_ylabel("trajectory distance to reduced at 1e-6 m")
    ax.set_title("speed against accuracy")
    fig.tight_layout()
    write_with(path, lambda tmp: fig.savefig(tmp, dpi=120, format=Path(path).suffix[1:]))
    plt.close(fig)
    return path


def write_engine_reports(results: dict[str, Any], out_dir: Path, figures: bool = True) -> None:
    """results.json, report.md and a self-contained report.html in ``out_dir``."""
    from .report import html_report, write_json

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
