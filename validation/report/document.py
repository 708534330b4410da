"""Writing results.json, report.md, report.html; comparing with a baseline.

The regression rules (``--baseline FILE``, exact or statistical mode) are in
:mod:`validation.regression.baseline`.
"""

from __future__ import annotations

import base64
import html
import json
import math
import re
from pathlib import Path
from typing import Any

import numpy as np

from cipcore.atomic import write_text
from validation.checks.divergence import group_lines
from validation.checks.stats import Check
from validation.paper.refs import printed
from validation.regression.baseline import compare_with_baseline as baseline_checks
from validation.regression.baseline import regression_numbers  # noqa: F401  (moved there; kept importable here)
from validation.report.captions import figure_caption, settings_rows


def jsonable(v: Any) -> Any:
    """Nested dicts / lists / numpy values as plain JSON values; NaN and inf become None."""
    if isinstance(v, dict):
        return {str(k): jsonable(x) for k, x in v.items()}
    if isinstance(v, list | tuple):
        return [jsonable(x) for x in v]
    if isinstance(v, np.ndarray):
        return jsonable(v.tolist())
    if isinstance(v, np.generic):
        return jsonable(v.item())
    if isinstance(v, float) and not math.isfinite(v):
        return None
    return v


def write_json(results: dict, path: Path) -> Path:
    """Write ``path`` atomically (a per-process temporary name, then os.replace)."""
    return write_text(path, json.dumps(jsonable(results), indent=1))


def _fmt(v: Any, missing: str = "n/a (not computed)") -> str:
    """A value for a Markdown cell: never empty, ``|`` escaped."""
    if v is None:
        return missing
    if isinstance(v, float):
        return f"{v:.4g}" if math.isfinite(v) else "n/a (no finite estimate)"
    if isinstance(v, list | tuple):
        return "[" + ", ".join(_fmt(x, "n/a") for x in v) + "]"
    return _cell(str(v))


def _cell(text: str) -> str:
    """Escape ``|`` so that a cell cannot break its Markdown table; never empty."""
    text = str(text).replace("\\|", "|").replace("|", "\\|").replace("\n", " ")
    return text if text.strip() else "n/a"


def split_row(line: str) -> list[str]:
    """The cells of one Markdown table row ``| a | b |`` (``\\|`` kept as a literal ``|``)."""
    return [c.strip().replace("\\|", "|") for c in re.split(r"(?<!\\)\|", line.strip().strip("|"))]


def markdown_tables(md: str) -> list[list[list[str]]]:
    """Every table of a Markdown text: rows of cells, the header first, the ``---`` row dropped."""
    tables: list[list[list[str]]] = []
    current: list[list[str]] | None = None
    for line in md.splitlines():
        if not line.startswith("|"):
            current = None
            continue
        if current is None:
            current = []
            tables.append(current)
        cells = split_row(line)
        if not set("".join(cells)) <= set("-:"):
            current.append(cells)
    return tables


def _row_cells(cells: list[Any]) -> str:
    return "| " + " | ".join(_fmt(c) for c in cells) + " |"


def paper_section(results: dict) -> list[str]:
    """The paper table, claim by claim, and the robustness table (validation.paper.claims).

    The function is long because it is the paper table's rows in order.
    """
    from validation.paper.claims import ROBUSTNESS_RULE, VERDICT_RULE

    lines = ["", "## Paper reproduction: the paper's claims, one row each", "",
             "System: which system the paper makes the claim about (the linear model of "
             "section 3 or the human experiment of section 4).  Status `not a check` rows are "
             "reported beside the table, with the reason in the note: they are claims about "
             "the experiment, one noise draw, or numbers set by an unstated initial condition.  "
             f"Status of a ratio claim: {VERDICT_RULE}.",
             "",
             "| claim | system | where in the paper | paper | ours | 95 % interval or SE "
             "| status | estimator and run | note |",
             "|---|---|---|---|---|---|---|---|---|"]  # fmt: skip
    checks = [r for r in results["paper"] if r["status"] != "not a check"]
    others = [r for r in results["paper"] if r["status"] == "not a check"]
    for r in checks + others:
        lines.append(
            _row_cells(
                [
                    r["quantity"],
                    r.get("system", "model"),
                    r.get("where", "n/a"),
                    r["paper"],
                    r["ours"],
                    _fmt(r["uncertainty"], "n/a (no interval)"),
                    r["status"],
                    r["settings"],
                    r.get("note") or "n/a (no note)",
                ]
            )
        )
    rob = results.get("robustness")
    if rob:
        lines += ["", "## Robustness of the model's claims to the estimator choices", "",
                  "Each claim re-estimated on the same simulations for every combination of "
                  "the estimator choices the paper leaves unstated.  An estimator choice "
                  "*supports* the claim when the 95 % bootstrap interval lies on the claimed "
                  "side (ratios) or the slopes agree / differ as claimed (within 2 / beyond 3 "
                  f"standard errors).  Verdict: {ROBUSTNESS_RULE}.", "",
                  "| claim | where | choices | supports / contradicts / inconclusive | "
                  "range of estimates | paper value inside the interval | supports by choice "
                  "| verdict |", "|---|---|---|---|---|---|---|---|"]  # fmt: skip
        for r in rob["summary"]:
            by = (
                "; ".join(
                    f"{k}: " + ", ".join(f"{v} {n}" for v, n in d.items())
                    for k, d in r["supports_by_choice"].items()
                )
                or "n/a (one choice)"
            )
            rng = (
                _fmt(r["estimate_range"])
                if r["estimate_range"]
                else "n/a (vector estimates; see results.json)"
            )
            lines.append(_row_cells([r["claim"], r["where"], r["n_choices"],
                                     f"{r['supports']} / {r['contradicts']} / "
                                     f"{r['inconclusive']}", rng, r["paper_in_ci"], by,
                                     r["verdict"]]))  # fmt: skip
        amp = rob.get("amplitude")
        if amp:
            d = amp["max_relative_difference_of_scaled_errors"]
            lines += [
                "",
                "Initial amplitude: the linear models scale exactly with it under "
                "the same noise (largest relative difference of the scaled errors "
                + ", ".join(f"{k} {v:.1e}" for k, v in d.items())
                + "), so every ratio and slope above is invariant; only absolute "
                "numbers (the paper's mean RMS 1.5e3 and 0.3) depend on it.",
            ]
    if results.get("nonlinear"):
        lines += [
            "",
            "## The nonlinear stick, eq. (1), beside the linear model",
            "",
            "| model | realisations x s | seed | low slope | high slope | crossover (Hz) "
            "| low slope = -1/2 | laminar exponent | laminar = -3/2 | largest abs error (m or rad) "
            "| fraction with abs theta > pi/2 |",
            "|---|---|---|---|---|---|---|---|---|---|---|",
        ]
        for r in results["nonlinear"]:
            lines.append(_row_cells([
                r["model"], f"{r['realizations']} x {r['duration']:g}", r["seed"],
                f"{r['slope_low']:.3g} +- {r['slope_low_se']:.2g}", r["slope_high"],
                r["crossover"], "yes" if r["low_is_minus_half"] else "no",
                (f"{r['laminar_slope']:.3g} +- {r['laminar_se']:.2g}"
                 if r["laminar_slope"] is not None and math.isfinite(r["laminar_slope"])
                 else "n/a (fewer than 3 populated bins)"),
                "yes" if r["laminar_is_minus_three_halves"] else "no", r["max_abs"],
                _fmt(r["fallen_fraction"], "n/a (linear model: no angle)")]))  # fmt: skip
    return lines


def _not_applicable(results: dict) -> str:
    """', N n/a' where a tier left checks that do not judge the engine, else ''."""
    n = results["counts"].get("n/a", 0)
    return f", {n} n/a (not the engine's tier)" if n else ""


def markdown(results: dict, regression: list[Check] | None = None) -> str:
    """The function is long because it is the report's template, section by section."""
    from validation.cli.checklog import check_value

    # the validated engine as the figures name it (its family); MuJoCo in older results
    engine = ((results.get("engine") or {}).get("capabilities") or {}).get("family") or "MuJoCo"
    lines = [
        "# cipval validation report",
        "",
        f"Profile **{results['profile']}**, overall status **{results['status'].upper()}** "
        f"({results['counts']['pass']} pass, {results['counts']['fail']} fail, "
        f"{results['counts']['inconclusive']} inconclusive{_not_applicable(results)}), "
        f"{results['elapsed_s']} s.",
        "",
        "Versions: " + ", ".join(f"{k} {v}" for k, v in results["versions"].items()),
        "",
        "## Checks",
        "",
        "| check | status | value | tolerance |",
        "|---|---|---|---|",
    ]
    for c in results["checks"]:
        lines.append(
            _row_cells(
                [
                    c["name"],
                    c["status"],
                    check_value(c),
                    c["tolerance"] or "n/a (no tolerance)",
                ]
            )
        )
    if regression:
        lines += [
            "",
            "## Regression against the baseline",
            "",
            "| number | status | value | baseline | change | tolerance |",
            "|---|---|---|---|---|---|",
        ]
        for c in regression:
            v = c.values
            rel = _fmt(v.get("relative_change"), "n/a (baseline 0 or NaN)")
            change = f"z = {_fmt(v['z'])}" if "z" in v else f"relative {rel}"
            lines.append(f"| {c.name} | {c.status} | {_fmt(v.get('value'))} | "
                         f"{_fmt(v.get('baseline'))} | {change} | {c.tolerance} |")  # fmt: skip
    lines += paper_section(results)
    lines += ["", "## Amplitude scan (full vs reduced, same noise)", "",
              "| model | initial error (m) | largest abs theta (rad) | reference's (rad) | "
              "rel. L2 | trajectory | RMS | spectrum |",
              "|---|---|---|---|---|---|---|---|"]  # fmt: skip
    for r in results["amplitude_scan"]:
        ref = _fmt(r.get("reference_max_abs_angle"))
        ref += " (engine left the regime)" if r.get("engine_left_regime") else ""
        lines.append(f"| {r['model']} | {r['amplitude']:g} | {r['max_abs_angle']:.3g} | {ref} | "
                     f"{r['relative_l2']:.3g} | {r['trajectory']} | {r['log10_rms']} | "
                     f"{r['spectrum_bands']} |")  # fmt: skip
    if results.get("rod_length"):
        lines += [
            "",
            f"## Rod-length study ({engine}, coupled, same noise at every point)",
            "",
            "Per point: the median over realisations [5 %, 95 % of them] (these quantities are "
            "heavy-tailed; a mean with its interval would cross 0), or the mean +- its 95 % "
            "half-width where the run kept no quantiles.",
            "",
            "| l / L | initial error (m) | largest abs theta (rad) | rel. L2 to reduced | "
            "log10 RMS | median tau_hat (s) |",
            "|---|---|---|---|---|---|",
        ]
        for r in results["rod_length"]:
            cells = [_spread(r, k) for k in ("max_angle", "agreement", "rms", "tau_hat")]
            lines.append(
                f"| {r['rod_length_ratio']:g} | {r['amplitude']:g} | " + " | ".join(cells) + " |"
            )
    lines += divergence_section(results)
    if results["figures"]:
        lines += ["", "## Figures", "",
                  *figure_lines(results["figures"], results["settings"], engine)]  # fmt: skip
    lines += ["", "## Settings", "", f"Profile {results['profile']}, grouped by the stage "
              "that uses them (s, m, Hz as stated).", "", "| stage | settings |",
              "|---|---|"]  # fmt: skip
    lines += [_row_cells([g, v]) for g, v in settings_rows(jsonable(results["settings"]))]
    lines.append("")
    return printed("\n".join(lines))  # the paper's labels as its printed numbers


def _spread(row: dict, key: str) -> str:
    """``median [q05, q95]`` of a rod-length row's metric, else ``mean +- half-width``."""
    q = row.get(key + "_q05_50_95")
    if q and all(v is not None for v in q):
        return f"{q[1]:.3g} [{q[0]:.3g}, {q[2]:.3g}]"
    ci = row.get(key + "_ci95")
    return _fmt(row.get(key)) + (f" +- {ci:.2g}" if ci is not None else "")


def figure_lines(names: list[str], settings: dict, engine: str = "MuJoCo") -> list[str]:
    """Markdown of the run's figures and clips: each image, then ``*Figure k.* caption``
    (the engine's data named ``engine``, :func:`validation.report.captions.figure_caption`)."""
    lines = []
    for k, f in enumerate(names, 1):
        caption = figure_caption(f, settings, engine).replace("\n", " ")
        lines += [f"![Figure {k}: {f}]({f})", "", f"*Figure {k}.* {caption}", ""]
    return lines


def divergence_section(results: dict) -> list[str]:
    """Where realisations diverged or left the small-angle regime, one line per stage."""
    entries = results.get("divergence") or []
    lines = ["", "## Divergence and departures from the small-angle regime", ""]
    if not entries:
        return [*lines, "No realisation of any stage diverged or left the small-angle regime."]
    return lines + [f"- {line}" for line in group_lines(entries)]


#: a figure's caption in the Markdown: the paragraph after its image, ``*Figure k.* text``
_CAPTION = re.compile(r"^\*(Figure \d+\.)\* (.*)$")


def html_report(md: str, out_dir: Path) -> str:
    """A self-contained HTML page: the Markdown's tables and text, figures embedded.

    An image line ``![alt](file)`` followed by a caption paragraph
    ``*Figure k.* text`` becomes one ``<figure>`` with that ``<figcaption>``.
    """
    body: list[str] = []
    in_table = in_list = False
    lines = md.splitlines()
    skip: set[int] = set()
    for i, line in enumerate(lines):
        if i in skip:
            continue
        if line.startswith("|"):
            cells = split_row(line)
            if set("".join(cells)) <= {"-"}:
                continue
            tag = "th" if not in_table else "td"
            if not in_table:
                body.append("<table>")
                in_table = True
            cls = ""
            if tag == "td" and len(cells) > 1:
                st = cells[1]
                cls = f' class="{st}"' if st in ("pass", "fail", "inconclusive") else ""
            body.append(f"<tr{cls}>" + "".join(f"<{tag}>{html.escape(c)}</{tag}>" for c in cells)
                        + "</tr>")  # fmt: skip
            continue
        if in_table:
            body.append("</table>")
            in_table = False
        if in_list and not line.startswith("- "):
            body.append("</ul>")
            in_list = False
        if line.startswith("!["):
            alt = line[2 : line.index("](")]
            name = line[line.index("](") + 2 : -1]
            data = base64.b64encode((out_dir / name).read_bytes()).decode()
            mime = "image/gif" if name.endswith(".gif") else "image/png"
            j = i + 1
            while j < len(lines) and not lines[j].strip():
                j += 1
            m = _CAPTION.match(lines[j]) if j < len(lines) else None
            if m:
                skip.add(j)
                cap = f"<b>{html.escape(m.group(1))}</b> {html.escape(m.group(2))}"
            else:
                cap = html.escape(alt)
            body.append(f'<figure><img src="data:{mime};base64,{data}" alt="{html.escape(alt)}">'
                        f"<figcaption>{cap}</figcaption></figure>")  # fmt: skip
        elif line.startswith("#"):
            level = len(line) - len(line.lstrip("#"))
            body.append(f"<h{level}>{html.escape(line.lstrip('# '))}</h{level}>")
        elif line.startswith("```"):
            body.append("<pre>" if line == "```json" else "</pre>")
        elif line.startswith("- "):
            if not in_list:
                body.append("<ul>")
                in_list = True
            body.append(f"<li>{html.escape(line[2:])}</li>")
        elif line:
            text = html.escape(line).replace("**", "")
            body.append(f"<p>{text}</p>")
    if in_table:
        body.append("</table>")
    if in_list:
        body.append("</ul>")
    style = ("body{font-family:sans-serif;max-width:1100px;margin:auto}table{border-collapse:"
             "collapse;font-size:13px}td,th{border:1px solid #ccc;padding:3px 6px}"
             "tr.pass td:nth-child(2){background:#d4f4d4}tr.fail td:nth-child(2)"
             "{background:#f8d0d0}tr.inconclusive td:nth-child(2){background:#f8f0c0}"
             "img{max-width:100%}figure{margin:1.5em 0}figcaption{font-size:14px;"
             "max-width:900px;color:#222;margin-top:4px}")  # fmt: skip
    return (f"<!doctype html><html><head><meta charset='utf-8'><title>cipval report</title>"
            f"<style>{style}</style></head><body>{''.join(body)}</body></html>")  # fmt: skip


def write_reports(results: dict, out_dir: Path, regression: list[Check] | None = None) -> None:
    write_json(results, out_dir / "results.json")
    md = markdown(results, regression)
    write_text(out_dir / "report.md", md)
    write_text(out_dir / "report.html", html_report(md, out_dir))


def summary_table(results: dict, regression: list[Check] | None = None) -> str:
    """The terminal table (:func:`validation.cli.checklog.check_table`) and the counts; moved
    regression numbers are listed by :func:`validation.cli.checklog.regression_log`."""
    from validation.cli.checklog import check_table

    out = [check_table(results["checks"])]
    c = results["counts"]
    out.append(f"\n{c['pass']} pass, {c['fail']} fail, {c['inconclusive']} inconclusive"
               f"{_not_applicable(results)} ({results['profile']} profile, "
               f"{results['elapsed_s']} s)")  # fmt: skip
    return "\n".join(out)


# ------------------------------------------------------------ regression
def compare_with_baseline(results: dict, baseline: dict, mode: str = "auto") -> list[Check]:
    """:func:`validation.regression.baseline.compare_with_baseline` of the run's plain
    JSON values."""
    return baseline_checks(jsonable(results), baseline, mode)
