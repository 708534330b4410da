"""The experiment's report: Tables STCC and RMS, Figs. move_s, move_c, stcc_s, stcc_c, rmstau.

Markdown and a self-contained HTML page (the suite's
:func:`validation.report.document.html_report`), plus ``results.json``.  Where the
recordings name subjects A and B, the paper's numbers for pair (A, B) stand
beside ours, in the same unit only: tau_hat in s, RMS beside our RMS in
pixels (the paper's RMS, 2.0 .. 6.1, has the size of pixels; its unit is not
stated); our RMS in model units has a table of its own.  Every recording is
shown; duplicates of (mode, subject, trial index) are listed, and trials cut
short from outside (:data:`.analysis.INCOMPLETE`) are marked and left out of
the averages unless ``include_incomplete``.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from cipcore import Trajectory
from cipcore.atomic import write_text, write_with
from cipcore.models import MODEL_NAMES, get_model
from validation.checks import metrics
from validation.experiment.analysis import (
    INCOMPLETE,
    PAPER_AB,
    PAPER_AB_AVERAGE,
    PAPER_QUANTITY,
    UNITS,
    StickResult,
    analyse_directory,
    condition_ellipses,
    duplicates,
    mean_stcc,
    table,
    trial_tau_hat,
)
from validation.report.document import html_report, jsonable


def _f(v: float, digits: int = 3) -> str:
    return "–" if v is None or not np.isfinite(v) else f"{v:.{digits}g}"


def _cell(row: dict, k: int, digits: int) -> str:
    """The values of trial index ``k`` (several for duplicates, " / " between them); one
    left out of the average is followed by its end reason in brackets."""
    if k not in row["trials"]:
        return ""
    cells = zip(row["trials"][k], row["ends"][k], row["used"][k], strict=True)
    return " / ".join(_f(v, digits) + ("" if used else f" [{end}]") for v, end, used in cells)


def markdown_table(rows: dict, title: str, quantity: str, digits: int) -> list[str]:
    """One of the paper's tables: subjects by trial index, with the average, all in the
    unit of ``quantity`` (:data:`.analysis.UNITS`); the paper's average stands beside ours
    only where it is in the same unit (:data:`.analysis.PAPER_QUANTITY`)."""
    unit = UNITS[quantity]
    paper_q = PAPER_QUANTITY.get(quantity)
    idx = sorted({k for r in rows.values() for k in r["trials"]})
    cols = [*map(str, idx), f"average ({unit})", f"sd ({unit})", "n used"]
    if paper_q:
        cols.append(f"paper (A,B) average ({'s' if quantity == 'tau_hat' else 'unit not stated'})")
    lines = [f"### {title}", "", "| subject | " + " | ".join(cols) + " |",
             "|" + "---|" * (len(cols) + 1)]  # fmt: skip
    for mode in MODEL_NAMES:
        keys = [k for k in rows if k[0] == mode]
        if not keys:
            continue
        lines.append(f"| **{mode}:** |" + " |" * len(cols))
        for key in keys:
            r = rows[key]
            vals = [_cell(r, k, digits) for k in idx]
            vals += [_f(r["average"], digits + 1), _f(r["std"], 2), str(r["n"])]
            if paper_q:
                paper = PAPER_AB_AVERAGE[paper_q].get(key)
                vals.append(_f(paper, digits + 1) if paper else "")
            lines.append(f"| {key[1]} | " + " | ".join(vals) + " |")
    return [*lines, ""]


def paper_rows(quantity: str, digits: int) -> list[str]:
    """The paper's Table STCC or RMS for pair (A, B), for comparison."""
    lines = ["| paper (A,B) | 1 | 2 | 3 | 4 | 5 | average |", "|---|---|---|---|---|---|---|"]
    for key, vals in PAPER_AB[quantity].items():
        avg = PAPER_AB_AVERAGE[quantity][key]
        lines.append(f"| {key[0]} {key[1]} | " + " | ".join(f"{v:g}" for v in vals)
                     + f" | {avg:g} |")  # fmt: skip
    return [*lines, ""]


# ---------------------------------------------------------------- figures
def _pick(trajs: dict[str, Trajectory], results: list[StickResult], mode: str) -> list[tuple]:
    """(trajectory, stick, subject) to draw for ``mode``: subjects A and B when present,
    else the first two subjects, from their longest trial."""
    best: dict[str, tuple] = {}
    for r in results:
        if r.mode != mode:
            continue
        if r.subject not in best or r.duration > best[r.subject][3]:
            best[r.subject] = (trajs[r.file], r.stick - 1, r.subject, r.duration)
    names = [s for s in ("A", "B") if s in best] or sorted(best)[:2]
    return [best[n][:3] for n in names]


def _save(fig, path: Path) -> None:
    """Write ``fig`` to ``path`` (90 dpi, the format of its extension) atomically."""
    write_with(path, lambda tmp: fig.savefig(tmp, dpi=90, format=Path(path).suffix[1:]))


def fig_move(picks, mode: str, path: Path) -> Path:
    """Velocities of target and subject over 5 s, and spectra of the balancing error
    with the two power-law fits (paper Figs. move_s, move_c)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(2, len(picks), figsize=(5.5 * len(picks), 6.5), squeeze=False)
    for j, (traj, i, subject) in enumerate(picks):
        dt = traj.sample_interval
        t = traj.time
        sel = (t >= min(10.0, t[-1] / 2)) & (t < min(10.0, t[-1] / 2) + 5.0)
        tip = "x_T" if get_model(mode).n_controllers == 1 else "q_T"
        base = "x_M" if get_model(mode).n_controllers == 1 else f"q_M{i + 1}"
        ax[0, j].plot(t[sel], traj["tip_velocity"][0, sel, i], lw=2.2, label=f"{tip}' (target)")
        ax[0, j].plot(t[sel], traj["base_velocity"][0, sel, i], lw=0.9, label=f"{base}' (subject)")
        ax[0, j].set(
            xlabel="t (s)", ylabel="velocity (units/s)", title=f"{mode}: subject {subject}"
        )
        ax[0, j].legend(fontsize=8)
        e = traj["balancing_error"][0, :, i]
        if e.size * dt >= 40.0:
            f, s = metrics.power_spectrum(e, dt)
            ax[1, j].loglog(f, s, lw=0.8, color="0.3")
            fit = metrics.fit_two_power_laws(f, s[None, :], fmax=min(20.0, 0.8 / (2 * dt)))
            for lo, hi, slope in ((fit.fmin, fit.crossover, fit.slope_low),
                                  (fit.crossover, fit.fmax, fit.slope_high)):  # fmt: skip
                ff = np.geomspace(lo, hi, 20)
                # anchored at the mean log spectrum within a factor 1.5 of the crossover
                near = (f > fit.crossover / 1.5) & (f < fit.crossover * 1.5)
                s_c = 10 ** np.mean(np.log10(s[near])) if near.any() else np.nan
                ax[1, j].loglog(ff, s_c * (ff / fit.crossover) ** slope, "--", lw=1.8,
                                label=f"slope {slope:.2f}")  # fmt: skip
            ax[1, j].legend(fontsize=8)
        else:
            ax[1, j].text(0.5, 0.5, "trial too short for a spectrum (< 40 s)",
                          ha="center", transform=ax[1, j].transAxes)  # fmt: skip
        err = "Delta x" if get_model(mode).n_controllers == 1 else f"Delta q_{i + 1}"
        ax[1, j].set(xlabel="f (Hz)", ylabel=f"S of {err}")
    fig.tight_layout()
    _save(fig, path)
    plt.close(fig)
    return path


def fig_stcc(picks, mode: str, path: Path) -> Path:
    """Window-averaged STCC R(x_T', x_M'; tau) with tau_hat marked (paper Figs. stcc_s, stcc_c)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.5, 4))
    for traj, i, subject in picks:
        dt = traj.sample_interval
        vt, vm = traj["tip_velocity"][0, :, i], traj["base_velocity"][0, :, i]
        if vt.size * dt < 5.5:
            continue
        lags, r, _ = mean_stcc(vt, vm, dt)
        th = trial_tau_hat(lags, r, vt.size)
        ax.plot(lags, r, marker=".", label=f"{subject}: tau_hat = {_f(th, 2)} s")
        if np.isfinite(th):
            ax.axvline(th, ls=":", color=ax.lines[-1].get_color())
    ax.set(xlabel="tau (s)", ylabel="R", title=f"STCC, {mode}")
    if ax.lines:
        ax.legend()
    else:
        ax.text(
            0.5,
            0.5,
            "no trial long enough: STCC windows need trials of at least 5.5 s",
            transform=ax.transAxes,
            ha="center",
            va="center",
        )
    fig.tight_layout()
    _save(fig, path)
    plt.close(fig)
    return path


def fig_rmstau(results: list[StickResult], ellipses: dict, path: Path) -> Path:
    """tau_hat against RMS over all trials, mean +- sd ellipses per condition (Fig. 16)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.patches import Ellipse

    fig, ax = plt.subplots(figsize=(6.5, 4.5))
    style = {"single": ("^", "-"), "coupled": ("s", "--")}
    for mode, (marker, ls) in style.items():
        pts = [(r.tau_hat, r.rms) for r in results if r.mode == mode]
        if not pts:
            continue
        x, y = np.array(pts).T
        ax.plot(x, y, marker, ls="none", label=mode, alpha=0.8)
        el = ellipses.get(mode)
        if el and np.isfinite(el["sd_tau_hat"]) and np.isfinite(el["sd_rms"]):
            ax.add_patch(Ellipse((el["mean_tau_hat"], el["mean_rms"]), 2 * el["sd_tau_hat"],
                                 2 * el["sd_rms"], fill=False, ls=ls, lw=1.5))  # fmt: skip
    ax.set(xlabel="tau_hat (s)", ylabel="RMS of the balancing error (model units)",
           title="correlation time vs RMS")  # fmt: skip
    ax.legend()
    fig.tight_layout()
    _save(fig, path)
    plt.close(fig)
    return path


# ----------------------------------------------------------------- report
def write_report(
    directory: Path, out: Path, figures: bool = True, include_incomplete: bool = False
) -> list[Path]:
    """Analyse every recording in ``directory``; write report.md/html and results.json.

    Trials cut short from outside (:data:`.analysis.INCOMPLETE`) are shown but left out
    of the averages, the ellipses and Fig. 16 unless ``include_incomplete``.

    The function is long because it writes the report's sections in order, each beside its
    figure.
    """
    out.mkdir(parents=True, exist_ok=True)
    results, trajs = analyse_directory(directory)
    used = [r for r in results if include_incomplete or r.complete]
    ell = condition_ellipses(results, include_incomplete)
    rows = {q: table(results, q, include_incomplete) for q in ("tau_hat", "rms", "rms_px")}
    dups = duplicates(results)
    subjects = {r.subject for r in results}
    n_incomplete = sum(not r.complete for r in results)
    md = ["# The paper's experiment: analysis", "",
          f"Recordings: `{directory}`; {len(trajs)} trial(s), {len(results)} subject-trials, "
          f"{n_incomplete} of them cut short from outside ({', '.join(INCOMPLETE)}).",
          "tau_hat: first dominant peak of the STCC R(x_T', x_M'; tau) averaged over 5 s "
          "windows (every 1 s, lags to 0.5 s), in s; RMS of the balancing error, in model "
          "units (the screen spans -3 .. 3) and in pixels (1 unit = 1199/6 px).", "",
          ("Trials cut short from outside are **included** in the averages (as asked)."
           if include_incomplete else
           "Trials cut short from outside are shown with their end reason in brackets and "
           "**left out** of the averages, the ellipses and Fig. 16 "
           "(`--include-incomplete` includes them)."), "",
          "## Trials", "",
          "| file | mode | subject | trial | ended | in averages | duration (s) | tau_hat (s) "
          "| RMS (model units) | RMS (px) |",
          "|---|---|---|---|---|---|---|---|---|---|"]  # fmt: skip
    for r in results:
        md.append(f"| {r.file} | {r.mode} | {r.subject} | {r.trial_index} | {r.end} | "
                  f"{'yes' if include_incomplete or r.complete else 'no'} | "
                  f"{r.duration:.2f} | {_f(r.tau_hat, 2)} | {_f(r.rms, 3)} | "
                  f"{_f(r.rms_px, 3)} |")  # fmt: skip
    md.append("")
    if dups:
        md += ["## Duplicates", "",
               f"{len(dups)} (mode, subject, trial index) recorded more than once; every "
               "recording is kept and shown (values separated by ' / ' in the tables).", "",
               "| mode | subject | trial | files |", "|---|---|---|---|"]  # fmt: skip
        md += [f"| {d['mode']} | {d['subject']} | {d['trial_index']} | "
               f"{', '.join(d['files'])} |" for d in dups]  # fmt: skip
        md.append("")
    md += ["## Table STCC: correlation times tau_hat (s)", ""]
    md += markdown_table(rows["tau_hat"], "ours (s)", "tau_hat", 2)
    md += ["## Table RMS: RMS of the balancing errors", "",
           "The paper does not state the unit of its RMS values (2.0 .. 6.1); they have the "
           "size of screen pixels, so they stand beside our RMS in pixels only.", ""]  # fmt: skip
    md += markdown_table(rows["rms_px"], "ours, pixels (1 unit = 1199/6 px)", "rms_px", 3)
    md += markdown_table(rows["rms"], "ours, model units (no paper values in this unit)",
                         "rms", 3)  # fmt: skip
    if {"A", "B"} <= subjects:
        md += ["## The paper's numbers for pair (A, B)", "", "Table STCC (s):", ""]
        md += paper_rows("tau_hat", 2)
        md += ["Table RMS (unit not stated; the size of pixels):", ""]
        md += paper_rows("rms", 2)
    md += ["## Fig. 16: means and standard deviations per condition", "",
           "| condition | n | mean tau_hat (s) | sd tau_hat (s) | mean RMS (model units) "
           "| sd RMS (model units) |",
           "|---|---|---|---|---|---|"]  # fmt: skip
    for mode, e in ell.items():
        md.append(f"| {mode} | {e['n']} | {_f(e['mean_tau_hat'])} | {_f(e['sd_tau_hat'], 2)} |"
                  f" {_f(e['mean_rms'])} | {_f(e['sd_rms'], 2)} |")  # fmt: skip
    md.append("")
    names = []
    if figures:
        for mode, suffix in (("single", "s"), ("coupled", "c")):
            picks = _pick(trajs, results, mode)
            if picks:
                names.append(fig_move(picks, mode, out / f"move_{suffix}.png").name)
                names.append(fig_stcc(picks, mode, out / f"stcc_{suffix}.png").name)
        if used:
            names.append(fig_rmstau(used, ell, out / "rmstau.png").name)
        md += ["## Figures", ""] + [f"![{n}]({n})" for n in names]
    text = "\n".join(md) + "\n"
    write_text(out / "report.md", text)
    write_text(out / "report.html", html_report(text, out))
    res = {"trials": [r.as_dict() for r in results], "ellipses": ell, "duplicates": dups,
           "include_incomplete": include_incomplete, "units": UNITS,
           "table_stcc": {f"{k[0]} {k[1]}": v for k, v in rows["tau_hat"].items()},
           "table_rms": {f"{k[0]} {k[1]}": v for k, v in rows["rms"].items()},
           "table_rms_px": {f"{k[0]} {k[1]}": v for k, v in rows["rms_px"].items()},
           "figures": names}  # fmt: skip
    write_text(out / "results.json", json.dumps(jsonable(res), indent=1))
    return [out / "report.md", out / "report.html", out / "results.json"] + [out / n for n in names]
