"""``run --resume`` state: what is reused, what is recomputed and said so.

The stage computations are replaced by cheap stand-ins that count their calls,
so these tests check the resume rules (content hashes of ``--mjcf`` files,
damaged manifest or stage records, deleted figures) in milliseconds.
"""

from __future__ import annotations

import pytest

from cipcore.scenario import EngineTarget
from validation import run as harness
from validation.profiles import PROFILES
from validation.run import MODEL_FILE_STAGES, STAGES, RunSetting, run_validation


@pytest.fixture
def counted(monkeypatch):
    """Replace every stage by a stand-in; returns {stage: number of computations}."""
    calls = {name: 0 for name in STAGES}

    def stand_in(name):
        def compute(*args, **kwargs):
            calls[name] += 1
            return [] if name == "figures" else {"stage": name}

        return compute

    monkeypatch.setattr(harness, "conformance_and_anchors", stand_in("conformance and anchors"))
    monkeypatch.setattr(harness, "_engine_record", lambda *a, **k: {})
    monkeypatch.setattr(harness.agreement, "lyapunov_checks", stand_in("lambda1 agreement"))
    monkeypatch.setattr(harness.agreement, "series_checks", stand_in("time-series agreement"))
    monkeypatch.setattr(harness.agreement, "amplitude_scan", stand_in("amplitude scan"))
    monkeypatch.setattr(harness.paper, "critical_gains", stand_in("critical gains"))
    monkeypatch.setattr(harness.paper, "lyapunov_curve", stand_in("lambda1 curve"))
    monkeypatch.setattr(harness.paper, "rms_and_velocity", stand_in("RMS and velocity"))
    monkeypatch.setattr(harness.paper, "peaks_and_spectra", stand_in("STCC and spectra"))
    monkeypatch.setattr(harness.paper, "robustness", stand_in("robustness"))
    monkeypatch.setattr(harness.paper, "nonlinear_comparison", stand_in("nonlinear stick"))
    monkeypatch.setattr(harness.agreement, "rod_length_study", stand_in("rod-length study"))
    monkeypatch.setattr(harness, "_figures", stand_in("figures"))
    monkeypatch.setattr(harness, "spawn_figure_worker", lambda *a, **k: None)  # drawn in-process
    monkeypatch.setattr(harness, "_results", lambda *a, **k: {})
    return calls


def _run(out, files=None, resume=True):
    setting = RunSetting(PROFILES["smoke"], EngineTarget(files=files), figures=True,
                         resume=resume, progress=False)  # fmt: skip
    return run_validation(setting, out)


def test_editing_an_mjcf_file_recomputes_exactly_the_stages_that_read_it(counted, tmp_path, capsys):
    single = tmp_path / "my_single.xml"
    single.write_text("<mujoco/>  <!-- gravity 9.81 -->")
    files = {"single": str(single)}
    _run(tmp_path / "out", files, resume=False)
    assert all(n == 1 for n in counted.values())

    _run(tmp_path / "out", files)  # nothing changed: everything reused
    assert all(n == 1 for n in counted.values())

    single.write_text("<mujoco/>  <!-- gravity 9.7 -->")  # same path, other content
    capsys.readouterr()
    res = _run(tmp_path / "out", files)
    for name in STAGES:
        again = name in MODEL_FILE_STAGES or name == "figures"
        assert counted[name] == (2 if again else 1), name
    assert set(res["stages_reused"]) == set(STAGES) - set(MODEL_FILE_STAGES) - {"figures"}
    err = capsys.readouterr().err
    assert "other model file contents (single: " in err and "recomputed" in err


def test_damaged_manifest_is_a_stated_recompute_of_every_stage(counted, tmp_path, capsys):
    out = tmp_path / "out"
    _run(out, resume=False)
    (out / "stages" / "manifest.json").write_text('{"key": "ab')  # truncated
    capsys.readouterr()
    _run(out)
    assert all(n == 2 for n in counted.values())
    err = capsys.readouterr().err
    assert "manifest.json is damaged" in err and "every stage is recomputed" in err


def test_damaged_stage_record_is_a_stated_recompute_of_that_stage(counted, tmp_path, capsys):
    out = tmp_path / "out"
    _run(out, resume=False)
    rec = next((out / "stages").glob(f"{STAGES.index('critical gains')}-*.pkl"))
    rec.write_bytes(rec.read_bytes()[:5])
    capsys.readouterr()
    _run(out)
    assert counted["critical gains"] == 2 and counted["lambda1 curve"] == 1
    assert counted["figures"] == 2  # drawn from a recomputed stage
    assert "'critical gains'" in capsys.readouterr().err


def test_deleted_figure_is_redrawn(counted, tmp_path, monkeypatch, capsys):
    out = tmp_path / "out"

    def figures(out_dir, state, profile, engine="mujoco"):
        counted["figures"] += 1
        (out_dir / "fig_x.png").write_bytes(b"png")
        return [out_dir / "fig_x.png"]

    monkeypatch.setattr(harness, "_figures", figures)
    _run(out, resume=False)
    _run(out)
    assert counted["figures"] == 1
    (out / "fig_x.png").unlink()
    capsys.readouterr()
    _run(out)
    assert counted["figures"] == 2 and (out / "fig_x.png").is_file()
    assert "figure file(s) missing" in capsys.readouterr().err


def test_figure_child_process_failure_is_reported_and_an_unused_one_is_ended(tmp_path):
    """The paper figures' child process: a failure names its last error line; a worker
    never given its job (the run stopped first) is ended."""
    (tmp_path / harness.STAGE_DIR).mkdir()
    state = {"lambda1 agreement": (None, {"lyapunov": []}), "time-series agreement": (None, {}),
             "amplitude scan": (None, []), "critical gains": (None, None, {}),
             "lambda1 curve": {}, "RMS and velocity": (None, {}),
             "STCC and spectra": (None, {})}  # fmt: skip
    drawing = harness.start_paper_figures(tmp_path, state)
    with pytest.raises(RuntimeError, match=r"drawing the figures failed: .*Error"):
        harness.finish_paper_figures(drawing)
    harness.stop_paper_figures(drawing)
    assert not (tmp_path / harness.STAGE_DIR / "figures-job.pkl").exists()
    idle = harness.spawn_figure_worker(tmp_path)
    harness.stop_paper_figures(idle)
    assert idle[0].poll() is not None


def test_figure_child_process_draws_the_rod_length_figures_after_the_paper_job(tmp_path):
    """The figure worker takes a second job, the rod-length study's dataset, and draws
    its two figures (max angle, agreement against l / L); its job files are removed."""
    xr = pytest.importorskip("xarray")
    import numpy as np

    (tmp_path / harness.STAGE_DIR).mkdir()
    shape = (2, 2, 3)
    rng = np.random.default_rng(0)
    ds = xr.Dataset(
        {name: (("rod_length_ratio", "amplitude", "realization"), rng.uniform(0.01, 1, shape))
         for name in ("max_angle", "agreement")}
        | {"divergence_time": (("rod_length_ratio", "amplitude", "realization"),
                               np.full(shape, np.inf))},
        coords={"rod_length_ratio": [0.2, 2.0], "amplitude": [1e-3, 0.1],
                "realization": [0, 1, 2]},
    )  # fmt: skip
    worker = harness.spawn_figure_worker(tmp_path)
    files = harness.finish_paper_figures(worker, tmp_path, ds)
    assert [f.name for f in files] == ["fig_rod_length_max_angle.png",
                                       "fig_rod_length_agreement.png"]  # fmt: skip
    assert all(f.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" for f in files)
    harness.stop_paper_figures(worker)
    assert not list((tmp_path / harness.STAGE_DIR).glob("figures-*job.pkl"))


def test_each_paper_figure_is_ready_once_the_stages_it_draws_are_done():
    from validation.report.figures import PAPER_FIGURES

    assert set(harness.FIGURE_DATA_STAGES.values()) <= set(harness.STAGES)
    assert {k for keys in PAPER_FIGURES.values() for k in keys} == set(harness.FIGURE_DATA_STAGES)
    assert harness.ready_paper_figures(["conformance and anchors"]) == []
    done = ["conformance and anchors", "lambda1 agreement", "time-series agreement"]
    assert harness.ready_paper_figures(done) == ["fig_Be.png"]
    done += ["amplitude scan", "critical gains", "lambda1 curve"]
    ready = harness.ready_paper_figures(done, ["fig_Be.png"])
    assert ready == ["fig_lLe.png", "fig_amplitude_scan.png"]
    assert harness.ready_paper_figures(harness.STAGES) == list(PAPER_FIGURES)


def test_an_unknown_paper_figure_name_is_refused(tmp_path):
    pytest.importorskip("matplotlib")
    from validation.report import plots

    with pytest.raises(ValueError, match="no paper figure named"):
        plots.paper_figures(tmp_path, {}, only=["fig_nonesuch.png"])


def test_an_interrupt_before_the_results_file_still_names_every_kept_stage(
    counted, tmp_path, monkeypatch
):
    """SIGINT between a stage's record and the results file (the signal lands in
    ``write_json``): the results file is written again for the stages kept, so it, the
    interruption and ``--resume`` agree on them."""
    import json

    real = harness.write_json
    calls = []

    def interrupted_once(obj, path):
        calls.append(obj["stages_done"])
        if len(calls) == 2:  # the second stage is saved, its results file not yet written
            raise KeyboardInterrupt
        real(obj, path)

    monkeypatch.setattr(harness, "write_json", interrupted_once)
    monkeypatch.setattr(harness, "_results", lambda *a, **k: {})
    out = tmp_path / "out"
    with pytest.raises(harness.RunInterrupted) as exc:
        _run(out, resume=False)
    assert exc.value.kept == list(STAGES[:2])
    assert json.loads((out / "results.json").read_text())["stages_done"] == list(STAGES[:2])
    monkeypatch.setattr(harness, "write_json", real)
    res = _run(out)
    assert res["stages_reused"][:2] == list(STAGES[:2]) and counted[STAGES[1]] == 1


@pytest.mark.parametrize("signalled", [True, False])
def test_a_stage_failing_after_an_interrupt_signal_is_an_interruption(
    counted, tmp_path, monkeypatch, signalled
):
    """A KeyboardInterrupt inside an extension module's import comes out as another
    exception (pandas' C parser: ImportError, seen in the rod-length study's first import
    of xarray). After a signal that is the interruption, with the stages kept and no
    crash recorded; without one it stays a crash.  Here the second stage raises it."""
    import json

    arrived = {"signal": False}

    def imports_pandas(*args, **kwargs):
        arrived["signal"] = signalled  # the signal lands during the stage's import
        raise ImportError("pd_parser.c could not import module pandas")

    assert STAGES[1] == "time-series agreement"
    monkeypatch.setattr(harness.agreement, "series_checks", imports_pandas)
    monkeypatch.setattr(harness, "_results", lambda *a, **k: {})
    out = tmp_path / "out"
    expected = harness.RunInterrupted if signalled else harness.StageCrashed
    with pytest.raises(expected) as exc:
        setting = RunSetting(PROFILES["smoke"], progress=False)
        run_validation(setting, out, interrupted=lambda: arrived["signal"])
    assert exc.value.kept == [STAGES[0]]
    written = json.loads((out / "results.json").read_text())
    assert written["stages_done"] == [STAGES[0]]
    assert ("crashed" in written) is not signalled


def test_a_signal_whose_interrupt_was_lost_stops_the_run_before_the_next_stage(counted, tmp_path):
    """A signal arrived during the second stage, but its KeyboardInterrupt never reached
    the run (caught on the way): the run stops before the third stage, an interruption
    with the two stages kept, not a complete run."""
    import json

    done = []
    setting = RunSetting(PROFILES["smoke"], figures=False, progress=False)
    out = tmp_path / "out"
    with pytest.raises(harness.RunInterrupted) as exc:
        run_validation(setting, out, on_stage=lambda name, *_: done.append(name),
                       interrupted=lambda: len(done) >= 2)  # fmt: skip
    assert exc.value.kept == list(STAGES[:2]) and counted[STAGES[2]] == 0
    assert json.loads((out / "results.json").read_text())["stages_done"] == list(STAGES[:2])
