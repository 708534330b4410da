"""The paper table and robustness table: attribution, well-formed Markdown, re-estimation."""

from __future__ import annotations

import re

import numpy as np
import pytest

from validation.paper import claims as paper
from validation.profiles import PROFILES
from validation.report.document import markdown, paper_section


def _table_rows(md: str) -> list[list[str]]:
    """Rows of every Markdown table, split on unescaped pipes."""
    out = []
    for line in md.splitlines():
        if line.startswith("|"):
            out.append(re.split(r"(?<!\\)\|", line.strip())[1:-1])
    return out


def _check_tables(md: str) -> None:
    blocks, cur = [], []
    for line in [*md.splitlines(), ""]:
        if line.startswith("|"):
            cur.append(line)
        elif cur:
            blocks.append(cur)
            cur = []
    assert blocks
    for b in blocks:
        rows = _table_rows("\n".join(b))
        assert len({len(r) for r in rows}) == 1, b[0]  # no cell breaks its row
        for r in rows:
            assert all(c.strip() for c in r), r  # no empty cells
    assert not re.search(r"issue\s*#?\d|#\d+", md, re.IGNORECASE)


def test_paper_section_escapes_pipes_and_fills_missing_values():
    res = {"paper": [paper._row("|beta* - paper| <= 0.25", 1.0, None, None, "a | b",
                                "reproduced", "")],
           "robustness": {"summary": [{"claim": "x", "where": "section 3.2", "n_choices": 2,
                                       "supports": 1, "contradicts": 0, "inconclusive": 1,
                                       "estimate_range": None, "paper_in_ci": "1/2",
                                       "supports_by_choice": {},
                                       "verdict": "robust: reproduced"}]},
           "nonlinear": []}  # fmt: skip
    md = "\n".join(paper_section(res))
    _check_tables(md)
    assert "\\|beta* - paper\\|" in md and "n/a" in md


@pytest.fixture(scope="module")
def smoke_tables():
    p = PROFILES["smoke"]
    rows, _ = paper.rms_and_velocity(p, 2)
    rows2, data = paper.peaks_and_spectra(p, 2)
    rob = paper.robustness(p, 2)
    nl = paper.nonlinear_comparison(p, 2)
    paper.clear_cache()
    return rows + rows2, data, rob, nl


def test_every_row_is_attributed_and_experiment_claims_are_not_model_checks(smoke_tables):
    rows, _, rob, nl = smoke_tables
    for r in rows:
        assert r["system"] in ("model", "human experiment")
        assert re.search(r"section [1-5]", r["where"]), r
    exp = [r for r in rows if r["system"] == "human experiment"]
    assert exp and all(r["status"] == "not a check" for r in exp)
    # the -1/2 low-frequency law is the experiment's (section 4), never a model check
    half = [r for r in rows if r["paper"] == -0.5]
    assert half and all(r["system"] == "human experiment" and "section 4" in r["where"]
                        for r in half)  # fmt: skip
    assert {s["key"] for s in rob["summary"]} == set(paper.CLAIMS)
    for s in rob["summary"]:
        assert s["verdict"].startswith("robust: ") or s["verdict"] in (
            "estimator-dependent",
            "not reproduced",
            "inconclusive",
        )
    results = {"profile": "smoke", "status": "pass", "elapsed_s": 0, "versions": {},
               "counts": {"pass": 0, "fail": 0, "inconclusive": 0}, "checks": [],
               "paper": rows, "robustness": rob, "nonlinear": nl, "amplitude_scan": [],
               "figures": [], "settings": {}}  # fmt: skip
    _check_tables(markdown(results))


def test_robustness_re_estimates_one_set_of_simulations(smoke_tables):
    _, _, rob, _ = smoke_tables
    peaks = rob["outcomes"]["peak_height"]
    assert len(peaks) == 4  # windows 2.5, 5 x dominance 0.5, 0.8 in the smoke grid
    assert rob["amplitude"]["invariant"]
    # more estimator choices than simulations: the series were cached per model
    assert len({(e["choice"]["window"], e["choice"]["dominance"]) for e in peaks}) == 4
    assert np.isfinite([e["estimate"] for e in rob["outcomes"]["velocity"]]).all()


def test_ratio_status_separates_direction_magnitude_and_inconclusive():
    # the coupled / single RMS ratio of the quick run against the paper's 1 %
    assert paper.ratio_status(0.077, 0.66, 1e-2, "below") == "direction reproduced; magnitude not"
    assert paper.ratio_status(0.005, 0.66, 1e-2, "below") == "direction and magnitude reproduced"
    assert paper.ratio_status(0.005, 1.3, 1e-2, "below") == "inconclusive"
    # the velocity density ratio of the quick run: the paper's 2 excluded, 1 inside
    assert paper.ratio_status(0.83, 1.13, 2.0, "above") == "direction inconclusive; magnitude not"
    assert paper.ratio_status(1.1, 1.3, 1e-2, "below") == "not reproduced"
    assert paper.ratio_status(1.1, 1.9, 2.0, "above") == "direction reproduced; magnitude not"
    assert paper._verdict(["inconclusive"] * 24) == "inconclusive"
    assert paper._verdict(["inconclusive", "contradicts"]) == "not reproduced"
    assert paper._verdict(["supports", "inconclusive"]) == "estimator-dependent"
    assert paper._verdict(["supports"] * 2, [True, False]) == (
        "robust: direction reproduced; magnitude in 1/2 choices"
    )
    assert paper._verdict(["supports"] * 2, [False, False]) == (
        "robust: direction reproduced; magnitude not"
    )


def test_robustness_reuses_the_paper_stages_simulations(monkeypatch):
    """After the RMS and STCC stages the robustness stage simulates only its amplitude check,
    and its table is the one it computes from scratch (same draws, same numbers)."""
    import json

    p = PROFILES["smoke"]
    paper.clear_cache()
    fresh = paper.robustness(p, 2)
    paper.clear_cache()
    paper.rms_and_velocity(p, 2)
    paper.peaks_and_spectra(p, 2)
    calls = []
    real = paper.simulate
    monkeypatch.setattr(paper, "simulate", lambda *a, **k: calls.append(a) or real(*a, **k))
    shared = paper.robustness(p, 2)
    paper.clear_cache()
    assert len(calls) == 4  # amplitude_invariance: 2 models x 2 amplitudes, nothing else
    assert json.dumps(shared, sort_keys=True, default=str) == json.dumps(
        fresh, sort_keys=True, default=str
    )
