"""The run's report as a reader sees it: captions, legends, heavy tails, Chromium screenshots.

One smoke run for the session (``tests/conftest.py``).  Its figures are redrawn from the run's
saved stages with matplotlib's figures kept open, to check every panel's title
and legend and the axes of positive quantities; its ``report.html`` is opened
in Debian's Chromium driven by Playwright (skipped, with the reason, where
either is absent), screenshotted whole and figure by figure (saved under
``$CIPVAL_TEST_OUTPUT``, default: the test's tmp dir) and checked: one caption
per figure naming the paper's printed figure or saying there is none, no
empty figure.
"""

from __future__ import annotations

import json
import os
import pickle
import re
import shutil
from pathlib import Path

import numpy as np
import pytest

CHROMIUM = next((p for p in ("/usr/bin/chromium", shutil.which("chromium") or "") if p and
                 os.path.exists(p)), None)  # fmt: skip


@pytest.fixture(scope="module")
def smoke_run(smoke_run_once):
    code, out = smoke_run_once
    assert code == 0
    return out, json.loads((out / "results.json").read_text())


def _stage_state(out: Path) -> dict:
    from validation.run import STAGES

    state = {}
    for name in STAGES[:-1]:
        p = out / "stages" / f"{STAGES.index(name)}-{name.replace(' ', '_')}.pkl"
        state[name] = pickle.loads(p.read_bytes())["value"]
    return state


def test_every_figure_has_a_caption_naming_the_run_and_the_paper_figure(smoke_run):
    out, results = smoke_run
    md = (out / "report.md").read_text()
    seed = str(results["settings"]["seed"])
    paper = {"fig_lLe.png": 3, "fig_Be.png": 4, "fig_pwsp.png": 5, "fig_rms.png": 6,
             "fig_velo.png": 7, "fig_scc.png": 8, "fig_sccpeak.png": 9,
             "fig_sccpeak_pdf.png": 10}  # fmt: skip
    assert results["figures"]
    assert not re.search(r"Figs?\. (lLe|Be|pwsp|rms|velo|scc|sccpeak)\b|eq\. \(cabrera", md)
    for k, name in enumerate(results["figures"], 1):
        image = f"![Figure {k}: {name}]({name})"
        assert image in md
        caption = md.split(image, 1)[1].strip().splitlines()[0]
        assert caption.startswith(f"*Figure {k}.* ") and len(caption) > 200, caption
        assert f"seed {seed}" in caption and "realisations" in caption
        if name in paper:
            assert f"Redoes the paper's Fig. {paper[name]} (" in caption
        else:
            assert "No figure of the paper" in caption
        assert "lLe" not in caption and "sccpeak" not in caption  # printed numbers only


def test_report_tables_are_well_formed_and_settings_compact(smoke_run):
    from validation.report.document import markdown_tables

    out, _ = smoke_run
    md = (out / "report.md").read_text()
    for table in markdown_tables(md):
        assert all(len(row) == len(table[0]) for row in table), table[0]
    (rod,) = [t for t in markdown_tables(md) if t[0][0] == "l / L"]
    for row in rod[1:]:
        for cell in row[2:4]:  # largest |theta| and the distance: positive, heavy-tailed
            med, lo, hi = map(float, re.fullmatch(r"(\S+) \[(\S+), (\S+)\]", cell).groups())
            assert 0 <= lo <= med <= hi, cell
    settings = md.split("## Settings", 1)[1]
    assert "```" not in settings and settings.count("\n|") <= 16  # a table, not a JSON dump
    assert "| rod-length study |" in settings and "seed = 2011" in settings


def test_every_panel_has_a_title_and_a_legend_and_positive_axes(smoke_run, tmp_path, monkeypatch):
    """Redraw the run's figures, keeping each matplotlib figure to inspect its axes.

    Nothing is rasterised: the checks read the figures' artists, and ``savefig`` (nearly
    all of a figure's cost) writes an empty file; the run's own PNGs are checked in
    Chromium below."""
    import matplotlib.pyplot as plt
    from matplotlib.figure import Figure

    from validation.profiles import PROFILES
    from validation.run import _figures

    out, _ = smoke_run
    kept = []
    monkeypatch.setattr(plt, "close", lambda fig=None: kept.append(fig))
    monkeypatch.setattr(Figure, "savefig", lambda self, fname, **kw: Path(fname).touch())
    files = _figures(tmp_path, _stage_state(out), PROFILES["smoke"])
    assert len(kept) == len(files) == 11
    for fig, path in zip(kept, files, strict=True):
        axes = [ax for ax in fig.axes if ax.get_label() != "<colorbar>"]
        for ax in axes:
            assert ax.get_title() or fig._suptitle is not None, path.name
            legend = ax.get_legend() or (fig.legends[0] if fig.legends else None)
            assert legend is not None and legend.get_texts(), f"{path.name}: no legend"
        for ax in axes:
            lo, hi = ax.get_ylim()
            if "|theta|" in ax.get_ylabel() or "distance" in ax.get_ylabel():
                assert lo >= 0 and (hi <= np.pi + 1e-9 or "distance" in ax.get_ylabel()), path
    rms = kept[[p.name for p in files].index("fig_rms.png")]
    (ax,) = rms.axes
    assert ax.get_yscale() == "log"
    texts = [t.get_text() for t in ax.get_legend().get_texts()]
    assert any("beyond L (diverged" in t for t in texts)
    assert {
        "geometric mean",
        "central 50 % of realisations",
        "central 90 % of realisations",
    } <= set(texts)
    monkeypatch.undo()
    for fig in kept:
        plt.close(fig)


def test_rms_beyond_the_pendulum_length_is_counted_as_diverged(tmp_path, monkeypatch):
    """Synthetic heavy tail: the figure and the divergence list count the same realisations."""
    import matplotlib.pyplot as plt

    from validation.checks.divergence import group_lines, rms_divergence
    from validation.report.plots import fig_rms

    length = 0.446
    rng = np.random.default_rng(1)
    single = np.minimum(np.exp(rng.normal(-3, 2, 50)), 0.4)  # spans decades, all below L
    single[[3, 7, 11]] = [2.0, 1.6e4, np.inf]
    rms = {"single": {"rms": single}, "coupled": {"rms": np.exp(rng.normal(-5, 1, 50))}}
    ev = rms_divergence(rms, length)
    assert len(ev) == 1 and ev[0]["realizations"] == [3, 7, 11]
    assert "3 of 50 realisations diverged" in ev[0]["summary"]
    (line,) = group_lines(ev)
    assert line.startswith("RMS and velocity, single reduced: 3 of 50")
    kept = []
    monkeypatch.setattr(plt, "close", lambda fig=None: kept.append(fig))
    fig_rms(rms, tmp_path / "rms.png", length)
    monkeypatch.undo()
    texts = [t.get_text() for t in kept[0].axes[0].get_legend().get_texts()]
    assert "single: 3 of 50 beyond L (diverged, x)" in texts
    assert "coupled: 0 of 50 beyond L (diverged, x)" in texts
    plt.close(kept[0])


def test_intended_divergence_is_one_line():
    from validation.checks.divergence import group_lines

    why = "fell (|theta| > pi/2): largest |theta| 3.14 rad (intended: the scan looks for the "
    scan = [{"stage": "amplitude scan", "run": f"{m} amplitude {a:g} m", "intended": True,
             "summary": why + "breakdown)"}
            for m in ("single", "coupled") for a in (0.1, 0.3)]  # fmt: skip
    rod = [{"stage": "rod-length study", "run": f"l/L={x}", "summary": "realisations [1] of 3"}
           for x in (1, 2)]  # fmt: skip
    lines = group_lines(scan + rod)
    assert len(lines) == 2
    assert lines[0].startswith(
        "amplitude scan, intended (the scan looks for the breakdown), 4 runs"
    )
    assert lines[0].count("intended") == 1 and lines[0].count("fell") == 4
    assert lines[1].startswith("rod-length study, 2 runs: l/L=1: ")


@pytest.mark.skipif(CHROMIUM is None, reason="no Chromium (apt-get install chromium); CI has it")
def test_report_in_chromium_shows_captioned_non_empty_figures(smoke_run, tmp_path):
    sync_api = pytest.importorskip("playwright.sync_api", reason="playwright is not installed")
    out, results = smoke_run
    shots = Path(os.environ.get("CIPVAL_TEST_OUTPUT", tmp_path))
    shots.mkdir(parents=True, exist_ok=True)
    with sync_api.sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, args=["--no-sandbox"])
        try:
            page = browser.new_page(viewport={"width": 1280, "height": 900})
            page.goto((out / "report.html").as_uri())
            page.screenshot(path=str(shots / "report_page.png"), full_page=True)
            figs = page.query_selector_all("figure")
            assert len(figs) == len(results["figures"])
            for k, fig in enumerate(figs, 1):
                img = fig.query_selector("img")
                size = img.evaluate("i => [i.naturalWidth, i.naturalHeight, i.complete]")
                assert size[0] > 300 and size[1] > 200 and size[2], size
                cap = fig.query_selector("figcaption")
                text = cap.inner_text()
                assert text.startswith(f"Figure {k}.") and len(text) > 200, text[:80]
                assert cap.bounding_box()["height"] > 20  # shown, not hidden
                png = shots / f"report_figure_{k}.png"
                fig.screenshot(path=str(png))
                from PIL import Image

                with Image.open(png) as im:
                    pix = np.asarray(im.convert("L"), dtype=float)
                top = pix[: int(pix.shape[0] * 0.6)]  # the image, above its caption
                assert top.std() > 10 and (top < 128).mean() > 0.01, f"figure {k} looks empty"
            body = page.inner_text("body")
            assert "Divergence and departures from the small-angle regime" in body
            assert "intended (the scan looks for the breakdown)" in body
        finally:
            browser.close()


def test_paper_labels_become_printed_numbers():
    """Numbers from the order of the paper's captions (Fig. 4 is the one its text calls 4(a))."""
    from validation.paper.refs import printed

    assert printed("section 3.2, Figs. Be, rms") == "section 3.2, Figs. 4, 6"
    assert printed("Fig. sccpeak:pdf (100 realisations)") == "Fig. 10 (100 realisations)"
    assert printed("Fig. sccpeak: first") == "Fig. 9: first"
    assert printed("section 4.3, Tab. STCC, Figs. stcc_s, stcc_c") == (
        "section 4.3, Table 1, Figs. 14, 15"
    )
    assert printed("eq. (cabrera); eq. sss08:TM") == "eq. (1); eq. (5)"
    assert printed("Fig. rmstau, fig_rms.png, Fig. 3") == "Fig. 16, fig_rms.png, Fig. 3"


def test_figures_keep_the_report_order_though_drawn_as_their_stages_finish(smoke_run):
    """The figure process draws each paper figure as soon as its stages are done (so in
    another order); the report lists them in the paper's order, rod-length figures
    after, and no job file is left behind."""
    from validation.report.figures import PAPER_FIGURES, ROD_METRICS

    out, results = smoke_run
    names = [Path(f).name for f in results["figures"]]
    assert names[: len(PAPER_FIGURES)] == list(PAPER_FIGURES)
    rod = [f"fig_rod_length_{m}.png" for m in ROD_METRICS]
    assert names[len(PAPER_FIGURES) : len(PAPER_FIGURES) + len(rod)] == rod
    assert not list((out / "stages").glob("figures-*job.pkl"))


def test_figures_and_captions_name_the_engine_that_ran(smoke_run, tmp_path, monkeypatch):
    """The engine's data is labelled with its family in every figure and caption that
    shows it (they all said "MuJoCo" whatever the engine); the clips stay MuJoCo's."""
    import matplotlib.pyplot as plt
    from matplotlib.figure import Figure

    import validation.run as run
    from validation.profiles import PROFILES
    from validation.report.captions import figure_caption
    from validation.report.document import markdown

    assert run.engine_label("mujoco") == "MuJoCo"
    out, _ = smoke_run
    kept = []
    monkeypatch.setattr(plt, "close", lambda fig=None: kept.append(fig))
    monkeypatch.setattr(Figure, "savefig", lambda self, fname, **kw: Path(fname).touch())
    monkeypatch.setattr(run, "engine_label", lambda engine: {"drake": "Drake"}[engine])
    files = run._figures(tmp_path, _stage_state(out), PROFILES["smoke"], engine="drake")
    monkeypatch.undo()
    shows = {"fig_lLe.png", "fig_Be.png", "fig_pwsp.png", "fig_sccpeak_pdf.png",
             "fig_amplitude_scan.png"}  # fmt: skip
    for fig, path in zip(kept, files, strict=True):
        texts = [fig._suptitle.get_text()] if fig._suptitle is not None else []
        for ax in fig.axes:
            texts.append(ax.get_title())
            legend = ax.get_legend() or (fig.legends[0] if fig.legends else None)
            texts += [t.get_text() for t in legend.get_texts()] if legend else []
        words = " ".join(texts)
        assert "MuJoCo" not in words, path.name
        assert ("Drake" in words) == (path.name in shows), path.name
        plt.close(fig)
    res = json.loads((out / "results.json").read_text())
    res["engine"]["capabilities"]["family"] = "Drake"
    md = markdown(res)
    assert "## Rod-length study (Drake," in md
    assert "Drake (dashed)" in figure_caption("fig_Be.png", res["settings"], "Drake")
    assert "simulated by MuJoCo" in figure_caption("clip_inside_small_angle.gif", res["settings"],
                                                   "Drake")  # fmt: skip
