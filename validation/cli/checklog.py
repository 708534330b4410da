"""The terminal log of a run: a value and a tolerance for every check, moved numbers grouped.

A person reading a CI log acts on three things: which check failed, by how
much (the value against its tolerance), and, for a regression, which numbers
moved and by what relative change.  :func:`check_table` prints one row per
check with ``value`` and ``tolerance`` columns (a check made of sub-checks,
e.g. the twin's metrics or the spectral bands, shows its worst sub-check);
:func:`regression_log` groups moved numbers by check, lists only primary
numbers (a check's value, its paired difference, a distance) unless
``verbose``, and gives each number's relative change.
"""

from __future__ import annotations

import math
import re
from typing import Any

__all__ = [
    "DERIVED_KEYS",
    "check_table",
    "check_tolerance",
    "check_value",
    "regression_log",
    "tolerance_limit",
    "with_limit",
]

#: Leaves of a check's values derived from its primary numbers (intervals, standard
#: errors, margins, the comparison's own z): listed only with ``--verbose``.
DERIVED_KEYS = (
    "se",
    "ci95",
    "difference_ci95",
    "margin",
    "z",
    "sigma",
    "half_width_1",
    "half_width_2",
    "floor",
    "n",
    "relative_change",
    "implied_stiffness",
    "twin_stiffness",
    "uncertainty",
)


def _fmt(v: Any) -> str:
    if v is None:
        return "n/a (NaN)"
    if isinstance(v, bool):
        return str(v)
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        return "nan" if math.isnan(v) else f"{v:.4g}"
    return str(v)


def _worst_sub(values: dict) -> tuple[str, dict] | None:
    """The sub-check (a dict with a ``status``) that decides: a failed one, else the largest
    paired difference relative to its allowance."""
    subs: list[tuple[str, dict]] = []
    for k, v in values.items():
        if isinstance(v, dict) and "status" in v:
            subs.append((k, v))
        elif isinstance(v, list):
            subs += [
                (f"{k}[{i}]", x) for i, x in enumerate(v) if isinstance(x, dict) and "status" in x
            ]
    if not subs:
        return None

    def badness(item: tuple[str, dict]) -> tuple[int, float]:
        d = item[1]
        rank = {"fail": 2, "inconclusive": 1}.get(d.get("status", ""), 0)
        diff = abs(d.get("difference_mean") or 0.0)
        allow = d.get("margin") or d.get("floor") or 0.0
        return rank, diff / allow if allow else diff

    return max(subs, key=badness)


def _first_number(v: Any, path: str = "") -> tuple[str, Any] | None:
    if isinstance(v, bool) or isinstance(v, str):
        return None
    if v is None or isinstance(v, int | float):
        return path, v
    items = v.items() if isinstance(v, dict) else enumerate(v) if isinstance(v, list) else ()
    for k, x in items:
        key = f"{path}.{k}" if isinstance(k, str) else f"{path}[{k}]"
        found = _first_number(x, key.lstrip("."))
        if found is not None:
            return found
    return None


def check_value(c: dict) -> str:
    """The check's deciding number as ``name = value`` (never empty)."""
    v = c.get("values", {})
    for key in ("value", "relative_l2", "difference_mean", "measured_steps", "difference"):
        if key in v and not isinstance(v[key], dict | list):
            return f"{key} = {_fmt(v[key])}"
    if isinstance(v.get("difference"), dict) and "value" in v["difference"]:
        return f"difference = {_fmt(v['difference']['value'])}"
    sub = _worst_sub(v)
    if sub is not None:
        name, d = sub
        return f"worst {name}: " + check_value({"values": d})
    if "largest_agreeing_angle" in v:  # None: a metric agreeing at no amplitude scanned
        angles = [a for a in v["largest_agreeing_angle"].values() if a is not None]
        return "largest agreeing |theta| = " + (_fmt(min(angles)) if angles else "none")
    if "disagreeing" in v:
        return f"{len(v['disagreeing'])} of {len(v.get('far_amplitudes', []))} disagree"
    for key in ("slope_low", "slope_high"):
        if isinstance(v.get(key), dict) and "z" in v[key]:
            zs = {k: d["z"] for k, d in v.items() if isinstance(d, dict) and "z" in d}
            k = max(zs, key=lambda n: zs[n] if zs[n] is not None else math.inf)
            return f"worst {k}: z = {_fmt(zs[k])}"
    if isinstance(v.get("timestep"), dict):
        rel = [
            abs(d["model"] - d["controller"]) / abs(d["controller"])
            for d in v.values()
            if isinstance(d, dict) and d.get("controller")
        ]
        return f"largest relative mismatch = {_fmt(max(rel, default=0.0))}"
    first = _first_number(v)
    return f"{first[0]} = {_fmt(first[1])}" if first else f"status {c.get('status', '?')}"


_LIMIT = re.compile(r"(<=|<|within|beyond)\s*(\+-\s*)?([-+]?\d[\d.]*(?:e[-+]?\d+)?%?)")


def check_tolerance(c: dict) -> str:
    """A short statement of the check's tolerance with its number (the full text is in the
    report and results.json)."""
    v = c.get("values", {})
    if "margin" in v and v["margin"] is not None:
        return f"95% CI of diff. within +-{_fmt(v['margin'])}"
    if "half_width_1" in v:
        return f"|diff.| <= {_fmt(max(v['half_width_1'], v['half_width_2']))} (CI overlap)"
    sub = _worst_sub(v)
    if sub is not None:
        d = sub[1]
        if d.get("margin") is not None:
            return f"95% CI of diff. within +-{_fmt(d['margin'])}"
        if d.get("floor") is not None:
            return f"95% CI of diff. + {_fmt(d['floor'])}"
    if isinstance(v.get("slope_low"), dict) and "z" in v["slope_low"]:
        return "z <= 2 (fail beyond 3)"
    if "paper" in v and "value" in v:
        m = _LIMIT.search(c.get("tolerance", ""))
        if m:
            return f"|value - paper {_fmt(v['paper'])}| {m.group(1)} {m.group(3)}"
    m = re.search(r"to (\d[\d.]*e[-+]?\d+) relative", c.get("tolerance", ""))
    if m:
        return f"relative {m.group(1)}"
    if "expected_steps" in v:
        return f"== {v['expected_steps']} steps"
    text = c.get("tolerance", "")
    m = _LIMIT.search(text)
    if m:
        return f"{m.group(1)} {m.group(3)}"
    return text[:40] + ("..." if len(text) > 40 else "")


def tolerance_limit(c: dict) -> dict | None:
    """The check's tolerance as a number: ``{"on": what is bounded, "limit": bound}`` (the
    bound holds on the absolute value; units those of the quantity), None where the rule has
    no single number (e.g. every amplitude of a scan must disagree)."""
    v = c.get("values", {})
    if v.get("margin") is not None:
        return {"on": "difference_ci95", "limit": float(v["margin"])}
    if "half_width_1" in v and v["half_width_1"] is not None:
        return {"on": "difference", "limit": float(max(v["half_width_1"], v["half_width_2"]))}
    sub = _worst_sub(v)
    if sub is not None:
        name, d = sub
        if d.get("margin") is not None:
            return {"on": f"{name}.difference_ci95", "limit": float(d["margin"])}
        if d.get("floor") is not None:
            return {"on": f"{name}.difference_mean - difference_ci95", "limit": float(d["floor"])}
    if isinstance(v.get("slope_low"), dict) and "z" in v["slope_low"]:
        return {"on": "z", "limit": 2.0}
    if "expected_steps" in v:
        return {"on": "measured_steps - expected_steps", "limit": 0.0}
    if isinstance(v.get("tolerance"), int | float):  # the check carries its own bound
        on = "value - paper" if "paper" in v else "difference" if "difference" in v else "value"
        return {"on": on, "limit": float(v["tolerance"])}
    if c.get("tolerance", "").startswith("equal to the paper's literal values"):
        return {"on": "value - paper", "limit": 0.0}
    text = c.get("tolerance", "")
    m = re.search(r"to (\d[\d.]*e[-+]?\d+) relative", text)
    if m:
        return {"on": "relative mismatch", "limit": float(m.group(1))}
    m = _LIMIT.search(text)
    if m and m.group(1) in ("<=", "<"):
        num = m.group(3)
        limit = float(num[:-1]) / 100 if num.endswith("%") else float(num)
        keys = ("stretch_relative_l2", "relative_l2", "value")
        on = next((k for k in keys if k in v), "relative_l2" if num.endswith("%") else "value")
        if "paper" in v:
            on = "value - paper"
        return {"on": on, "limit": limit}
    return None


def with_limit(c: dict) -> dict:
    """The check dict with its numeric ``tolerance_limit`` (:func:`tolerance_limit`)."""
    return {**c, "tolerance_limit": tolerance_limit(c)}


def check_table(checks: list[dict], extra: list[tuple[str, str, str, str]] = ()) -> str:
    """One row per check: name, status, value, tolerance."""
    rows = [(c["name"], c["status"], check_value(c), check_tolerance(c)) for c in checks]
    rows += list(extra)
    w = max([len(r[0]) for r in rows] + [5])
    wv = max([len(r[2]) for r in rows] + [5])
    out = [f"{'check':<{w}}  {'status':<12}  {'value':<{wv}}  tolerance", "-" * (w + wv + 40)]
    out += [f"{n:<{w}}  {s:<12}  {v:<{wv}}  {t}" for n, s, v, t in rows]
    return "\n".join(out)


def _owner(path: str, names: list[str]) -> str:
    """The check a regression number belongs to (the longest check name prefixing it)."""
    best = ""
    for n in names:
        if (path == n or path.startswith(n + ".") or path.startswith(n + "[")) and len(n) > len(
            best
        ):
            best = n
    return best or path.split(".", 1)[0]


def _derived(path: str, owner: str) -> bool:
    parts = re.split(r"[.\[]", path[len(owner) :])
    return any(
        p.rstrip("]").rstrip("0123456789") in DERIVED_KEYS or p in DERIVED_KEYS for p in parts if p
    )


def regression_log(
    regression: list[Any], check_names: list[str], verbose: bool = False
) -> list[str]:
    """Lines naming the moved numbers, grouped by check, with the relative change."""
    moved = [c.as_dict() if hasattr(c, "as_dict") else c for c in regression]
    moved = [c for c in moved if c["status"] == "fail"]
    groups: dict[str, list[dict]] = {}
    for c in moved:
        path = c["name"].removeprefix("regression.")
        groups.setdefault(_owner(path, check_names), []).append({**c, "path": path})
    lines = []
    for owner, items in groups.items():
        shown = [c for c in items if verbose or not _derived(c["path"], owner)]
        hidden = len(items) - len(shown)
        if not shown:  # only derived numbers moved: show the first, so the group is not empty
            shown, hidden = items[:1], len(items) - 1
        lines.append(f"  {owner}: {len(items)} number(s) moved")
        for c in shown:
            v, vb = c["values"].get("value"), c["values"].get("baseline")
            if c.get("details"):
                change = c["details"]
            elif isinstance(v, int | float) and isinstance(vb, int | float) and vb != 0:
                change = f"relative change {(v - vb) / abs(vb):+.3g}"
            else:
                change = "changed"
            sub = c["path"][len(owner) :].lstrip(".") or "value"
            lines.append(f"    {sub}: {_fmt(vb)} -> {_fmt(v)} ({change})")
        if hidden:
            lines.append(
                f"    ... and {hidden} derived number(s) (intervals, standard "
                "errors, margins; --verbose lists them)"
            )
    return lines
