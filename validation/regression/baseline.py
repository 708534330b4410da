"""Comparing a run with a baseline results file: exact, round-off or statistical.

With the same seeds, a run reproduces every number of its baseline exactly
when nothing that decides round-off changed (:mod:`validation.regression.fingerprint`:
package versions, CPU architecture and instruction-set flags, numpy/BLAS
build, the kernels OpenBLAS chose for the CPU; not the kernel's build string), so
the comparison has three modes:

* **exact** (all of those match): every number of every check (values,
  distances, residuals, measured delays, the paired differences) and of the
  paper table must be reproduced to a relative 1e-12 (bit for bit in
  practice); each moved number is named with its old and new value.
* **roundoff** (same package versions, another CPU, numpy/BLAS build or BLAS
  kernels, or a baseline that does not record them): every number again, each to
  |new - old| <= :data:`ROUNDOFF_RTOL` max(|new|, |old|) + :data:`ROUNDOFF_ATOL`;
  measured delays (integers) exactly.  A number named ``difference`` recorded
  beside the two numbers it is the difference of is held relative to them
  (:func:`difference_scales`): the difference of two numbers near 22 that each
  move by round-off moves by their round-off, 1e3 times its own size (measured:
  ``anchor.stability_boundary.coupled``, 22.022 - 22.000, moved 2.3e-11 between
  OpenBLAS's Haswell and SkylakeX kernels, a relative 1.04e-9 of the difference
  against 1.04e-12 of its operands).  Measured: forcing OpenBLAS onto another
  CPU's kernels (``OPENBLAS_CORETYPE=Prescott``, with numba compiled for a
  generic CPU and numpy's AVX2/AVX-512 dispatch off) moved 96 of the smoke
  profile's 684 numbers; every move was at most 6.7e-15 absolute (differences
  of nearly equal numbers) or 5.8e-16 relative.  The tolerances leave room for
  round-off that grows along a simulated trajectory (the twin's own tolerance
  is 1e-9) and are far below any fault the suite catalogues.
* **statistical** (another MuJoCo / numpy / numba / ... version, where
  round-off and algorithms differ): numbers carried with a paired standard
  error (``{"value", "se"}``, e.g. the full - reduced paired differences) may
  move by at most :data:`Z_REGRESSION` of those standard errors combined; the
  distances and residuals (``relative_l2``) by at most
  :data:`DISTANCE_TOLERANCE`, the rod's stretch residual (a round-off floor)
  by at most the rod check's tolerance; measured delays (steps) not at all.

``mode="auto"`` picks the mode (:func:`choose_mode`) and says which and why; a
baseline made from other model files (``--mjcf``, by content digest) is
refused in ``auto`` and compared only in a mode asked for by name.
"""

from __future__ import annotations

import itertools
import math
from typing import Any

from cipcore.params import ParameterError
from validation.checks.stats import FAIL, PASS, Check

Z_REGRESSION = 4.0
EXACT_RTOL = 1e-12
#: Largest move of a distance or residual between platforms (absolute): ten
#: times MuJoCo's twin tolerance (cip.engines.rigid_body.RigidBodyEngine.twin_tolerance), i.e. far
#: above the round-off differences of a correct engine, far below a fault.
DISTANCE_TOLERANCE = 1e-8
#: The rod's stretch vs the twin is itself a round-off floor (6e-5 to 8e-5; it
#: moved by 2.5e-7 between MuJoCo 4.0.0 and 3.5.0): it may move up to the rod
#: check's own tolerance for MuJoCo (cip.engines.rigid_body.RigidBodyEngine.rod_tolerance).
DISTANCE_KEYS = {"relative_l2": DISTANCE_TOLERANCE, "stretch_relative_l2": 1e-3}
STEP_KEYS = ("measured_steps", "expected_steps")
#: Round-off tier (same package versions, another CPU or numpy/BLAS build): every
#: deterministic number to this relative tolerance (see the module docstring).
ROUNDOFF_RTOL = 1e-9
#: ... plus this absolute term for numbers that are differences of nearly equal ones.
ROUNDOFF_ATOL = 1e-12
MODES = ("auto", "exact", "roundoff", "statistical")


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


def difference_scales(results: dict) -> dict[str, float]:
    """The scale of each number named ``difference`` that has its operands beside it.

    Where a check's values hold ``difference`` and two other numbers ``a``, ``b``
    with ``a - b == difference`` (to relative 1e-12 of max(|a|, |b|)), the path of
    the difference (as :func:`all_numbers` names it) maps to max(|a|, |b|): round-off
    in ``a`` and ``b`` reaches the difference at that scale, not at its own.
    """
    out: dict[str, float] = {}

    def num(x: Any) -> bool:
        return isinstance(x, int | float) and not isinstance(x, bool) and math.isfinite(x)

    def walk(prefix: str, v: Any) -> None:
        if isinstance(v, dict):
            d = v.get("difference")
            if num(d):
                others = [x for k, x in v.items() if k != "difference" and num(x)]
                scales = [max(abs(a), abs(b)) for a, b in itertools.permutations(others, 2)
                          if abs(a - b - d) <= 1e-12 * max(abs(a), abs(b))]  # fmt: skip
                if scales:
                    out[f"{prefix}.difference"] = max(scales)
            for k, x in v.items():
                walk(f"{prefix}.{k}", x)
        elif isinstance(v, list):
            for i, x in enumerate(v):
                walk(f"{prefix}[{i}]", x)

    for c in results["checks"]:
        walk(c["name"], c["values"])
    return out


class BaselineMismatch(ParameterError):
    """The baseline was made from other model files: not a regression reference in ``auto``."""


def models_differ(results: dict, baseline: dict) -> str | None:
    """Why the two runs simulated different model files (by content digest), or None."""
    fr = (results.get("fingerprint") or {}).get("model_digests")
    fb = (baseline.get("fingerprint") or {}).get("model_digests")
    if fr is not None and fb is not None:
        diff = [k for k in sorted(set(fr) | set(fb)) if fr.get(k) != fb.get(k)]
        return f"model files differ ({', '.join(diff)})" if diff else None
    mr, mb = results.get("model_files") or {}, baseline.get("model_files") or {}
    return f"model files differ ({mr or 'shipped'} vs {mb or 'shipped'})" if mr != mb else None


def _numerics_diff(results: dict, baseline: dict) -> list[str] | None:
    """What of the CPU and numpy/BLAS build differs (empty: nothing), None if unrecorded."""
    fr, fb = results.get("fingerprint"), baseline.get("fingerprint")
    if not fr or not fb:
        return None
    out = []
    for key in ("machine", "cpu_flags", "numpy_build", "blas_kernels"):
        if key not in fb:
            out.append(f"the baseline does not record its {key.replace('_', ' ')}")
        elif fr.get(key) != fb.get(key):
            a, b = fb.get(key), fr.get(key)
            if isinstance(a, list) and isinstance(b, list):
                gone, new = sorted(set(a) - set(b)), sorted(set(b) - set(a))
                out.append(f"{key} " + " ".join([f"-{x}" for x in gone] + [f"+{x}" for x in new]))
            else:
                out.append(f"{key} {a} -> {b}")
    return out


def choose_mode(results: dict, baseline: dict, requested: str = "auto") -> tuple[str, str]:
    """(mode, reason), decided by what changes numbers (module docstring).

    ``auto``: exact when the package versions, the CPU architecture and
    instruction-set flags, the numpy/BLAS build and the BLAS kernels match the
    baseline's; round-off when only the CPU, the numpy/BLAS build or the BLAS
    kernels differ (or the baseline does not record them); statistical when a package version
    differs.  A baseline made from other model files raises
    :class:`BaselineMismatch` in ``auto`` (a requested mode compares anyway and
    says so).  The kernel's build string plays no part.
    """
    models = models_differ(results, baseline)
    vr, vb = results.get("versions", {}), baseline.get("versions", {})
    vdiff = [f"{k} {vb.get(k)} -> {vr.get(k)}" for k in sorted(set(vr) | set(vb))
             if vr.get(k) != vb.get(k)]  # fmt: skip
    ndiff = _numerics_diff(results, baseline)
    if requested != "auto":
        notes = [n for n in (models, ", ".join(vdiff), ", ".join(ndiff or [])) if n]
        return requested, "requested" + (f" ({'; '.join(notes)})" if notes else "")
    if models:
        raise BaselineMismatch(
            f"--baseline: {models}: the baseline is no regression reference for these "
            "models; make one from them (cip-validate baseline), or force a comparison with "
            "--baseline-mode statistical"
        )
    if vdiff:
        return "statistical", "package versions differ from the baseline's: " + ", ".join(vdiff)
    if ndiff is None:
        return "roundoff", ("same package versions; the baseline records no CPU or numpy/BLAS "
                            "fingerprint, so round-off may differ")  # fmt: skip
    if ndiff:
        return "roundoff", "same package versions; round-off may differ: " + ", ".join(ndiff)
    return "exact", ("same package versions, CPU architecture and instruction-set flags, "
                     "numpy/BLAS build and BLAS kernels as the baseline")  # fmt: skip


def _same(
    v: float | None,
    vb: float | None,
    rtol: float = EXACT_RTOL,
    atol: float = 0.0,
    scale: float = 0.0,
) -> bool:
    if v is None or vb is None:
        return v is vb
    if v == vb:
        return True
    return abs(v - vb) <= rtol * max(abs(v), abs(vb), scale) + atol


def compare_exact(
    results: dict, baseline: dict, rtol: float = EXACT_RTOL, atol: float = 0.0
) -> list[Check]:
    """One check per number: reproduced to relative ``rtol`` (+ ``atol``) or moved."""
    mode = "exact" if rtol == EXACT_RTOL else "roundoff"
    tol = f"relative {rtol:g}" + (f" + absolute {atol:g}" if atol else "")
    new, old = all_numbers(results), all_numbers(baseline)
    scales = difference_scales(baseline)
    for name, sc in difference_scales(results).items():
        scales[name] = max(sc, scales.get(name, 0.0))
    checks = []
    for name in sorted(set(new) | set(old)):
        if name not in new or name not in old:
            checks.append(Check(f"regression.{name}", FAIL,
                                {"value": new.get(name), "baseline": old.get(name)},
                                details="number missing on one side"))  # fmt: skip
            continue
        v, vb = new[name], old[name]
        exact_key = name.rsplit(".", 1)[-1] in STEP_KEYS  # integers: never round-off
        scale = scales.get(name, 0.0)
        if exact_key:
            ok = _same(v, vb, EXACT_RTOL, 0.0)
        else:
            ok = _same(v, vb, rtol, atol, scale)
        rel = None if v is None or vb is None or vb == 0 else (v - vb) / abs(vb)
        values = {"value": v, "baseline": vb, "relative_change": rel}
        if scale:
            values["operand_scale"] = scale
        checks.append(Check(
            f"regression.{name}", PASS if ok else FAIL, values,
            tolerance=f"{mode} mode: reproduced to "
            + (f"relative {EXACT_RTOL:g}" if exact_key else tol)
            + (" of its operands' size (a difference)" if scale and not exact_key else ""),
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
    if mode == "roundoff":
        return compare_exact(results, baseline, ROUNDOFF_RTOL, ROUNDOFF_ATOL)
    return compare_statistical(results, baseline)
