"""Comparing a run with a baseline results file: exact or statistical.

With the same seeds, a run reproduces every number of its baseline exactly
when nothing changed, so the comparison has two modes:

* **exact** (same platform and package versions): every number of every check
  (values, distances, residuals, measured delays, the paired differences) and
  of the paper table must be reproduced to a relative 1e-12 (bit for bit in
  practice); each moved number is named with its old and new value.
* **statistical** (another platform, or another MuJoCo / numpy / numba
  version, where round-off differs): numbers carried with a paired standard
  error (``{"value", "se"}``, e.g. the full - reduced paired differences) may
  move by at most :data:`Z_REGRESSION` of those standard errors combined; the
  distances and residuals (``relative_l2``) by at most
  :data:`DISTANCE_TOLERANCE`, the rod's stretch residual (a round-off floor)
  by at most the rod check's tolerance; measured delays (steps) not at all.

``mode="auto"`` picks exact when the recorded versions and platform match and
says which it chose and why.
"""

from __future__ import annotations

import math
from typing import Any

from .stats import FAIL, PASS, Check

Z_REGRESSION = 4.0
EXACT_RTOL = 1e-12
#: Largest move of a distance or residual between platforms (absolute): ten
#: times MuJoCo's twin tolerance (cip.engines.RigidBodyEngine.twin_tolerance), i.e. far
#: above the round-off differences of a correct engine, far below a fault.
DISTANCE_TOLERANCE = 1e-8
#: The rod's stretch vs the twin is itself a round-off floor (6e-5 to 8e-5; it
#: moved by 2.5e-7 between MuJoCo 4.0.0 and 3.5.0): it may move up to the rod
#: check's own tolerance for MuJoCo (cip.engines.RigidBodyEngine.rod_tolerance).
DISTANCE_KEYS = {"relative_l2": DISTANCE_TOLERANCE, "stretch_relative_l2": 1e-3}
STEP_KEYS = ("measured_steps", "expected_steps")
MODES = ("auto", "exact", "statistical")


def regression_numbers(results: dict) -> dict[str, tuple[float, float]]:
    """Every number carried with a standard error, by a dotted path."""
    out: dict[str, tuple[float, float]] = {}

    def walk(prefix: str, v: Any) -> None:
        if isinstance(v, dict):
            if "value" in v and "se" in v and v["value"] is not None and v["se"] is not None:
                out[prefix] = (float(v["value"]), float(v["se"]))
            for k, x in v.items():
                walk(f"{prefix}.{k}", x)

    for c in results["checks"]:
        walk(c["name"], c["values"])
    return out


def all_numbers(results: dict) -> dict[str, float | None]:
    """Every number (and None for a NaN) of the checks and the paper table, by path."""
    out: dict[str, float | None] = {}

    def walk(prefix: str, v: Any) -> None:
        if isinstance(v, dict):
            for k, x in v.items():
                walk(f"{prefix}.{k}", x)
        elif isinstance(v, list):
            for i, x in enumerate(v):
                walk(f"{prefix}[{i}]", x)
        elif isinstance(v, bool) or isinstance(v, str):
            return
        elif v is None or isinstance(v, int | float):
            out[prefix] = v

    for c in results["checks"]:
        walk(c["name"], c["values"])
    for r in results.get("paper", []):
        walk(f"paper.{r.get('quantity')}.{r.get('settings')}", {k: r.get(k) for k in
             ("paper", "ours", "uncertainty")})  # fmt: skip
    return out


def choose_mode(results: dict, baseline: dict, requested: str = "auto") -> tuple[str, str]:
    """(mode, reason): exact when versions and platform match, else statistical."""
    same_versions = results.get("versions") == baseline.get("versions")
    same_platform = results.get("platform") == baseline.get("platform")
    if requested != "auto":
        why = "requested"
        if requested == "exact" and not (same_versions and same_platform):
            why += " (versions or platform differ: round-off may move numbers)"
        return requested, why
    if same_versions and same_platform:
        return "exact", "package versions and platform match the baseline's"
    diff = [
        f"{k} {baseline.get('versions', {}).get(k)} -> {v}"
        for k, v in results.get("versions", {}).items()
        if baseline.get("versions", {}).get(k) != v
    ]
    if not same_platform:
        diff.append(f"platform {baseline.get('platform')} -> {results.get('platform')}")
    return "statistical", "differs from the baseline: " + ", ".join(diff)


def _same(v: float | None, vb: float | None) -> bool:
    if v is None or vb is None:
        return v is vb
    if v == vb:
        return True
    return abs(v - vb) <= EXACT_RTOL * max(abs(v), abs(vb))


def compare_exact(results: dict, baseline: dict) -> list[Check]:
    """One check per number: reproduced to relative 1e-12 or moved (old -> new)."""
    new, old = all_numbers(results), all_numbers(baseline)
    checks = []
    for name in sorted(set(new) | set(old)):
        if name not in new or name not in old:
            checks.append(Check(f"regression.{name}", FAIL,
                                {"value": new.get(name), "baseline": old.get(name)},
                                details="number missing on one side"))  # fmt: skip
            continue
        v, vb = new[name], old[name]
        ok = _same(v, vb)
        rel = None if ok or v is None or vb is None or vb == 0 else (v - vb) / abs(vb)
        checks.append(Check(
            f"regression.{name}", PASS if ok else FAIL,
            {"value": v, "baseline": vb, "relative_change": rel},
            tolerance=f"exact mode: reproduced to relative {EXACT_RTOL:g}",
        ))  # fmt: skip
    return checks


def compare_statistical(results: dict, baseline: dict) -> list[Check]:
    """Paired tolerances (module docstring) for numbers that may move by round-off."""
    checks = []
    new, old = regression_numbers(results), regression_numbers(baseline)
    for name in sorted(set(new) | set(old)):
        if name not in new or name not in old:
            checks.append(Check(f"regression.{name}", FAIL,
                                {"value": new.get(name, (None,))[0],
                                 "baseline": old.get(name, (None,))[0]},
                                details="number missing on one side"))  # fmt: skip
            continue
        (v, s), (vb, sb) = new[name], old[name]
        sigma = math.hypot(s, sb)
        z = abs(v - vb) / sigma if sigma > 0 else (0.0 if v == vb else math.inf)
        checks.append(Check(
            f"regression.{name}", PASS if z <= Z_REGRESSION else FAIL,
            {"value": v, "baseline": vb, "sigma": sigma, "z": z},
            tolerance=f"statistical mode: |value - baseline| <= {Z_REGRESSION:g} combined "
            "standard errors (paired ones for paired differences)",
        ))  # fmt: skip
    nall, oall = all_numbers(results), all_numbers(baseline)
    for name in sorted(set(nall) & set(oall)):
        key = name.rsplit(".", 1)[-1]
        v, vb = nall[name], oall[name]
        if key in DISTANCE_KEYS:
            ok = v is not None and vb is not None and abs(v - vb) <= DISTANCE_KEYS[key]
            tol = f"statistical mode: distance moves by <= {DISTANCE_KEYS[key]:g} (absolute)"
        elif key in STEP_KEYS:
            ok, tol = v == vb, "statistical mode: measured delay in steps unchanged"
        else:
            continue
        checks.append(Check(f"regression.{name}", PASS if ok else FAIL,
                            {"value": v, "baseline": vb}, tolerance=tol))  # fmt: skip
    return checks


def compare_with_baseline(results: dict, baseline: dict, mode: str = "auto") -> list[Check]:
    """Checks of a run (plain JSON values) against its baseline in ``mode`` (see module)."""
    mode, _ = choose_mode(results, baseline, mode)
    if mode == "exact":
        return compare_exact(results, baseline)
    return compare_statistical(results, baseline)
