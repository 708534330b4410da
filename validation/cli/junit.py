"""JUnit XML of a command's verdicts (``--junit FILE``), one test case per check.

CI systems (GitLab, Jenkins, GitHub's test reporters) read this format: a
``<testsuites>`` root, one ``<testsuite>`` per command (per engine for
``engines``), one ``<testcase>`` per check.  A failed check is a
``<failure>`` whose message carries the check's value and tolerance; an
inconclusive check (too few realisations to decide) and an engine that cannot
run here are ``<skipped>`` with the reason; an engine that crashed (``engines``) is
an ``<error>`` with the reason; a passing check has no child.
"""

from __future__ import annotations

import json
import xml.etree.ElementTree as ET
from collections.abc import Iterable
from pathlib import Path
from typing import Any

__all__ = ["Case", "engines_cases", "run_cases", "selftest_cases", "write_junit"]

#: (suite, classname, name, status, message, details): status pass / fail / error / skipped
Case = tuple[str, str, str, str, str, str]


def _status(s: str) -> str:
    return {"pass": "pass", "fail": "fail"}.get(s, "skipped")


def _classname(name: str) -> str:
    return name.rsplit(".", 1)[0] if "." in name else name


def run_cases(results: dict, regression: Iterable[Any] = (), suite: str = "run") -> list[Case]:
    """One case per check of a ``run`` results dict; with a baseline, one case for the
    regression comparison and one failure per moved number."""
    out: list[Case] = []
    for c in results.get("checks", []):
        msg = f"{c['status']}: {c.get('tolerance', '')}"
        det = json.dumps(c.get("values", {}), default=str)[:4000]
        out.append((suite, _classname(c["name"]), c["name"], _status(c["status"]), msg, det))
    crash = results.get("crashed")
    if crash:
        out.append(
            (
                suite,
                "stage",
                f"stage.{crash['stage']}",
                "fail",
                f"crashed: {crash['error']}",
                crash.get("traceback", ""),
            )
        )
    reg = [c.as_dict() if hasattr(c, "as_dict") else c for c in regression]
    if reg:  # one case for the comparison, one failure per moved number
        moved = [d for d in reg if d["status"] == "fail"]
        mode = (results.get("regression") or {}).get("mode", "")
        out.append((f"{suite}.regression", "regression", f"regression ({mode} mode)".strip(),
                    "fail" if moved else "pass",
                    f"{len(moved)} of {len(reg)} numbers moved beyond tolerance", ""))  # fmt: skip
        for d in moved:
            det = json.dumps(d.get("values", {}), default=str)
            out.append((f"{suite}.regression", _classname(d["name"]), d["name"], "fail",
                        f"moved: {d.get('tolerance', '')}", det))  # fmt: skip
    return out


def selftest_cases(clean: list[str], rows: list[dict]) -> list[Case]:
    """The unmodified model passes every check; each catalogued fault is flagged."""
    out: list[Case] = [
        (
            "selftest",
            "selftest",
            "unmodified_model",
            "fail" if clean else "pass",
            "checks failing on the unmodified model: " + ", ".join(clean),
            "",
        )
    ]
    for r in rows:
        name = f"fault.{r['fault']}"
        msg = (
            f"{r['fault']} ({r['size']:g} {r['unit']}) flagged by " + ", ".join(r["by"])
            if r["flagged"]
            else f"{r['fault']} ({r['size']:g} {r['unit']}) NOT flagged"
        )
        out.append(
            (
                "selftest",
                "selftest.fault",
                name,
                "pass" if r["flagged"] else "fail",
                msg,
                r.get("description", ""),
            )
        )
    return out


def engines_cases(results: dict) -> list[Case]:
    """One suite per engine, one case per check; an engine absent here is skipped, one that
    crashed an error."""
    out: list[Case] = []
    for r in results.get("engines", []):
        suite = f"engines.{r['engine']}"
        if r["status"] in ("skipped", "interrupted"):
            out.append((suite, suite, r["engine"], "skipped", r.get("reason", ""), ""))
            continue
        if r["status"] == "crashed":
            out.append((suite, suite, r["engine"], "error", r.get("reason", ""), ""))
            continue
        checks = r.get("checks", {})
        items = (
            checks.items()
            if isinstance(checks, dict)
            else ((c["name"], c["status"]) for c in checks)
        )
        for name, status in items:
            out.append((suite, suite, f"{r['engine']}.{name}", _status(status), status, ""))
    return out


def write_junit(cases: list[Case], path: Path | str, elapsed_s: float = 0.0) -> Path:
    """Write ``cases`` as JUnit XML to ``path`` (atomically: :mod:`cipcore.atomic`)."""
    from cipcore.atomic import write_with

    root = ET.Element("testsuites", name="cip-validate")
    suites: dict[str, ET.Element] = {}
    for suite, classname, name, status, message, details in cases:
        if suite not in suites:
            suites[suite] = ET.SubElement(root, "testsuite", name=suite)
        tc = ET.SubElement(suites[suite], "testcase", classname=classname, name=name, time="0")
        if status == "fail":
            el = ET.SubElement(tc, "failure", message=message[:1000], type="CheckFailed")
            el.text = details
        elif status == "error":
            ET.SubElement(tc, "error", message=message[:1000], type="EngineCrashed")
        elif status == "skipped":
            ET.SubElement(tc, "skipped", message=message[:1000])
    for s in [root, *suites.values()]:
        cs = s.iter("testcase")
        n = f = e = k = 0
        for tc in cs:
            n += 1
            f += tc.find("failure") is not None
            e += tc.find("error") is not None
            k += tc.find("skipped") is not None
        s.set("tests", str(n))
        s.set("failures", str(f))
        s.set("errors", str(e))
        s.set("skipped", str(k))
    root.set("time", f"{elapsed_s:.2f}")
    tree = ET.ElementTree(root)
    return write_with(path, lambda tmp: tree.write(tmp, encoding="utf-8", xml_declaration=True))
