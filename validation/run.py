"""``cip-validate run``: every check, the paper table, figures and the report.

Stages (each seeded from the profile's seed, so a rerun gives the same numbers
whatever the number of workers):

The engine under validation is any rigid-body engine of the registry
(``engine``, MuJoCo by default; ``integrator`` steps its model file with another
of MuJoCo's integrators): every engine goes through the same stages, checks
and tolerances (its twin and twin tolerance are its own).

0. the model files against the reduced model's specification
   (:mod:`validation.checks.conformance`) and the shared code's anchors
   (:mod:`validation.checks.anchors`);
1. lambda1 of the engine and the reduced model at a few gains (agreement);
2. time series of both engines at the paper's gains under the same noise,
   small amplitude: RMS, spectra, STCC peaks, velocity spread (agreement);
3. an amplitude scan: where the agreement breaks down;
4. paper reproduction with the reduced model: beta*, RMS, velocity density
   ratio, STCC at t = 36, tau_hat densities, spectral slopes, laminar phases;
5. the rod-length study;
6. figures redoing the paper's (from both models where it makes sense).

The report's two clips and its figures are drawn by child processes started
with the run (the figures' process gets the paper figures' data once the STCC
stage is done and the rod-length study's dataset once that stage is done, both
before robustness and the nonlinear stick), so they overlap the stages;
``--no-figures`` starts none of them.
Inside a run BLAS runs on one thread; the per-stage CPU seconds (this process
and its reaped children) are in ``results.json`` as ``cpu_s``.

Nothing finished is lost: each stage's outputs are written to
``DIR/stages/`` as soon as it finishes, and ``DIR/results.json`` is rewritten
atomically after every stage with ``"partial": true`` until the last.
``resume=True`` reuses the finished stages of a run with the same profile,
figures setting and package versions (the numbers are the same as a run
without interruption: every stage has its own seeds).
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import pickle
import sys
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from tqdm.auto import tqdm

from cipcore.atomic import WriteError, write_bytes
from cipcore.blas import one_blas_thread
from cipcore.params import BalanceParams, ParameterError
from cipcore.scenario import EngineTarget
from validation.checks import agreement
from validation.checks.stats import FAIL, INCONCLUSIVE, NOT_APPLICABLE, PASS
from validation.cli.checklog import with_limit
from validation.cli.ci_options import run_environment
from validation.paper import claims as paper
from validation.profiles import PAPER_BETA, Profile
from validation.regression.versions import package_versions
from validation.report.document import write_json

__all__ = ["STAGES", "RunInterrupted", "StageCrashed", "compile_note", "package_versions",
           "run_validation"]  # fmt: skip

#: the stages in the order they run (each is independent of the others' order: own seeds,
#: and the paper stages share simulations through a cache, the same numbers whichever
#: computes them first).  The figure process draws each figure once its stages are done,
#: so the stages with the most figures to draw come first and those with none last: the
#: rod-length study (two), the time series and the STCC (four), ..., the lambda1 stages
#: (one), then robustness, the nonlinear stick and the model files' conformance with the
#: anchors, which the drawing overlaps (with the conformance stage first, the figure
#: process waited idle for its first job: a smoke run took 5.74 s against 5.50 s, medians
#: of 3 side by side, ``benchmarks/bench_run.py --against 28cb82a``)
STAGES = ("rod-length study", "time-series agreement", "STCC and spectra",
          "RMS and velocity", "amplitude scan", "lambda1 agreement", "critical gains",
          "lambda1 curve", "robustness", "nonlinear stick", "conformance and anchors",
          "figures")  # fmt: skip
#: the order of the stages' checks and rows in ``results.json`` and the report: the model
#: files' conformance and the anchors first, whatever order the stages ran in
RESULT_ORDER = ("conformance and anchors", *(s for s in STAGES if s != "conformance and anchors"))
STAGE_DIR = "stages"


class StageCrashed(RuntimeError):
    """A stage raised (an engine crash): ``results.json`` was written, partial, naming it."""

    def __init__(self, stage: str, error: str, kept: list[str], out_dir: Path) -> None:
        super().__init__(f"stage {stage!r} crashed: {error}")
        self.stage, self.error, self.kept, self.out_dir = stage, error, kept, out_dir


class RunInterrupted(KeyboardInterrupt):
    """A run stopped by SIGINT / SIGTERM; ``kept`` names the stages saved in ``out_dir``."""

    def __init__(self, kept: list[str], out_dir: Path) -> None:
        super().__init__(f"kept {len(kept)} of {len(STAGES)} stages")
        self.kept = kept
        self.out_dir = out_dir


def compile_note() -> str | None:
    """A line to print when numba has no compiled kernels cached for the reduced model yet.

    numba caches compiled kernels (``*.nbi`` index files) in ``__pycache__``
    beside their modules, or under ``NUMBA_CACHE_DIR``; without them the first
    stage compiles (minutes on two cores).
    """
    import importlib.util

    spec = importlib.util.find_spec("reduced")
    if spec is None or not spec.submodule_search_locations:
        return None
    if os.environ.get("NUMBA_CACHE_DIR"):  # numba then caches there only
        where = [Path(os.environ["NUMBA_CACHE_DIR"])]
    else:
        where = [Path(p) / "__pycache__" for p in spec.submodule_search_locations]
    if any(any(d.rglob("*.nbi")) for d in where if d.is_dir()):
        return None
    return ("numba is compiling the reduced model's kernels (first run after install only; "
            "it adds to the first stage's time)")  # fmt: skip


def _file_digest(path: str | Path) -> str:
    """SHA-256 of a file's bytes (a model file edited in place changes the run key)."""
    try:
        return hashlib.sha256(Path(path).read_bytes()).hexdigest()
    except OSError as exc:
        raise ParameterError(f"--mjcf: cannot read {str(path)!r} ({exc.strerror})") from None


#: the stages that run a user's model file (``--mjcf``): their saved records carry the
#: files' content hashes and are recomputed when a file changed
MODEL_FILE_STAGES = ("conformance and anchors", "lambda1 agreement", "time-series agreement",
                     "amplitude scan")  # fmt: skip


def model_file_inputs(model_files: dict[str, str] | None) -> dict[str, list[str]]:
    """{model: [path, SHA-256 of its content]} of the ``--mjcf`` files."""
    return {k: [str(v), _file_digest(v)] for k, v in sorted((model_files or {}).items())}


def _run_key(
    profile: Profile,
    figures: bool,
    model_files: dict[str, str] | None = None,
    engine: str = "mujoco",
    integrator: str | None = None,
) -> str:
    """Hash of what fixes every stage's numbers: profile, figures setting, versions, and
    the engine and integrator where they are not the default.

    The model files' paths are in it; their contents enter the records of the stages
    that read them (:data:`MODEL_FILE_STAGES`), so editing one recomputes just those.
    """
    key = {"profile": profile.as_dict(), "figures": figures, "versions": package_versions(),
           "model_files": {k: str(v) for k, v in (model_files or {}).items()}}  # fmt: skip
    if engine != "mujoco" or integrator is not None:  # keys of default runs stay as they were
        key.update(engine=engine, integrator=integrator)
    return hashlib.sha256(json.dumps(key, sort_keys=True, default=str).encode()).hexdigest()[:16]


class _Stages:
    """``DIR/stages/``: one pickle per finished stage and a manifest naming the run."""

    def __init__(self, out_dir: Path, key: str, resume: bool) -> None:
        self.dir = out_dir / STAGE_DIR
        self.manifest = self.dir / "manifest.json"
        self.key = key
        old = self._read_manifest() if resume and self.manifest.is_file() else None
        if resume and old is not None and old.get("key") != key:
            raise ParameterError(
                f"--resume: {out_dir} holds stages of another profile, figures setting or "
                "package versions; rerun without --resume (or use another --out)"
            )
        self.dir.mkdir(parents=True, exist_ok=True)
        if not resume or old is None:
            for f in self.dir.glob("*.pkl"):
                f.unlink()
            _atomic(self.manifest, json.dumps({"key": key}).encode())

    def _read_manifest(self) -> dict | None:
        """The manifest, or None (every stage recomputed, said on stderr) when damaged."""
        try:
            old = json.loads(self.manifest.read_text())
        except (OSError, ValueError) as exc:
            why = " ".join(str(exc).split())
        else:
            if isinstance(old, dict) and isinstance(old.get("key"), str):
                return old
            why = "no run key in it"
        _note(f"--resume: {self.manifest} is damaged ({why}); every stage is recomputed")
        return None

    def _path(self, name: str) -> Path:
        return self.dir / f"{STAGES.index(name)}-{name.replace(' ', '_')}.pkl"

    def load(self, name: str, inputs: dict | None = None) -> Any:
        """The saved record of stage ``name`` if whole and made from ``inputs``, else None."""
        p = self._path(name)
        if not p.is_file():
            return None
        try:
            saved = pickle.loads(p.read_bytes())
        except Exception as exc:  # a damaged file (any unpickling error): recompute the stage
            why = f"{type(exc).__name__}: {' '.join(str(exc).split())}"
        else:
            if not (isinstance(saved, dict) and {"value", "seconds"} <= set(saved)):
                why = "not a stage record"
            elif saved.get("inputs", {}) != (inputs or {}):
                _note(
                    f"--resume: stage {name!r} was computed from other model file contents "
                    f"({_changed(saved.get('inputs', {}), inputs or {})}); it is recomputed"
                )
                return None
            else:
                missing = [f for f in saved["value"] if not (self.dir.parent / Path(f).name)
                           .is_file()] if name == "figures" else []  # fmt: skip
                if not missing:
                    return saved
                _note(
                    f"--resume: {len(missing)} figure file(s) missing from "
                    f"{self.dir.parent} ({Path(missing[0]).name}, ...); figures are redrawn"
                )
                return None
        _note(f"--resume: stage {name!r} ({p}) is damaged ({why}); the stage is recomputed")
        return None

    def save(self, name: str, value: Any) -> None:
        _atomic(self._path(name), pickle.dumps(value, protocol=pickle.HIGHEST_PROTOCOL))


def _changed(old: dict, new: dict) -> str:
    names = sorted({k for k in {*old, *new} if old.get(k) != new.get(k)})
    return ", ".join(f"{k}: {(new.get(k) or old.get(k))[0]}" for k in names)


def _note(text: str) -> None:
    tqdm.write(f"cip-validate: {text}", file=sys.stderr)


def _atomic(path: Path, data: bytes) -> None:
    write_bytes(path, data)


def conformance_and_anchors(profile: Profile, model_files: dict[str, str] | None) -> list:
    """The first stage: the model files against the reduced model's specification
    (:mod:`validation.checks.conformance`) and the shared code's anchors
    (:mod:`validation.checks.anchors`)."""
    from validation.checks.anchors import anchor_checks
    from validation.checks.conformance import conformance_checks

    return conformance_checks(model_files, tuple(PAPER_BETA)) + anchor_checks(
        profile.seed_for("anchors"), model_files
    )


@dataclass(frozen=True)
class RunSetting:
    """Everything a ``cip-validate run`` is told: one value from the command line on.

    Attributes
    ----------
    profile : the sizes, gains and seeds (:mod:`validation.profiles`).
    target : the rigid-body engine validated, the MuJoCo integrator its model files
        are stepped with (default: the files') and the user's model files
        (``--mjcf``) run instead of the shipped ``models/cip_<model>.xml``.
    workers : worker threads (None: every core); the numbers do not depend on it.
    figures : draw the figures and clips.
    resume : reuse the stages a previous run in the same directory saved.
    progress : show a progress bar.
    """

    profile: Profile
    target: EngineTarget = EngineTarget()
    workers: int | None = None
    figures: bool = True
    resume: bool = False
    progress: bool = True


def run_validation(
    setting: RunSetting,
    out_dir: Path,
    *,
    on_stage: Callable[[str, float, bool], None] | None = None,
    interrupted: Callable[[], bool] | None = None,
) -> dict[str, Any]:
    """Run every stage of ``setting``; returns the results dictionary written to results.json.

    The function is long for a reason: it is the one place that orders the stages,
    saves each as it finishes and turns every way a run can end (done, interrupted,
    an engine crash, bad input, an unwritable output) into what is kept on disk.

    After each stage, ``DIR/results.json`` holds everything finished so far
    (``"partial": true``); ``on_stage(name, seconds, reused)`` is called then.
    On KeyboardInterrupt (SIGINT, or SIGTERM turned into one by the CLI) raises
    :class:`RunInterrupted` naming the stages kept; when a stage raises (an
    engine crash) writes ``results.json`` partial with ``"crashed"`` and raises
    :class:`StageCrashed`.  ``interrupted()`` says whether an interrupt signal has
    arrived (the CLI's :func:`validation.cli.args.interrupt_signals`): a KeyboardInterrupt
    raised inside an extension module's import can surface as another exception (a
    SIGTERM during the rod-length stage's first ``import xarray`` came out of pandas' C
    parser as ``ImportError``), so a stage that raises after one counts as interrupted,
    not crashed.  A script calling this needs an
    ``if __name__ == "__main__":`` guard: the rod-length stage's process pool
    (forkserver) imports the main module in its workers.
    """
    profile, workers, figures, resume = (
        setting.profile,
        setting.workers,
        setting.figures,
        setting.resume,
    )
    model_files = dict(setting.target.files) if setting.target.files else None
    engine, integrator = setting.target.engine, setting.target.integrator
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    store = _Stages(out_dir, _run_key(profile, figures, model_files, engine, integrator), resume)
    # what the numbers are computed with, recorded in every (partial) results file: read once
    environment = run_environment(model_files)
    engine_record: dict[str, Any] | None = None  # read with the first stage's results
    file_inputs = model_file_inputs(model_files)
    target = {"files": model_files, "engine": engine, "integrator": integrator}
    bar = tqdm(STAGES, desc="cip-validate", disable=not setting.progress, unit="stage")
    timings: dict[str, float] = {}
    cpu: dict[str, float] = {}  # CPU seconds per stage (this process and reaped children)
    done: list[str] = []
    reused: list[str] = []
    state: dict[str, Any] = {}
    # BLAS on one thread (cipcore.blas): the stages spread their realisations over threads
    # themselves, and BLAS threads on the small matrices here only spin
    blas = contextlib.ExitStack()
    blas.enter_context(one_blas_thread())
    # the report's clips need the profile alone: rendered by child processes beside the
    # stages (a resumed run starts them in the figures stage, if that is recomputed)
    rendering = start_clips(out_dir, profile) if figures and not resume else None
    # the paper figures' child process: started now (its imports), given its job once the
    # stages it draws are done
    worker = spawn_figure_worker(out_dir) if figures and not resume else None
    drawing = None
    sent: list[str] = []  # the paper figures given to the figure process
    seen: dict[str, tuple] = {}  # each stage's divergence rows, searched once (_divergence)

    def compute(name: str) -> Any:
        if name == "conformance and anchors":
            return conformance_and_anchors(profile, model_files)
        if name == "lambda1 agreement":
            return agreement.lyapunov_checks(profile, workers, **target)
        if name == "time-series agreement":
            return agreement.series_checks(profile, workers, **target)
        if name == "amplitude scan":
            return agreement.amplitude_scan(profile, workers, **target)
        if name == "critical gains":
            return paper.critical_gains(profile, workers)
        if name == "lambda1 curve":
            return paper.lyapunov_curve(profile, workers)
        if name == "RMS and velocity":
            return paper.rms_and_velocity(profile, workers)
        if name == "STCC and spectra":
            return paper.peaks_and_spectra(profile, workers)
        if name == "robustness":
            return paper.robustness(profile, workers)
        if name == "nonlinear stick":
            nonlinear = paper.nonlinear_comparison(profile, workers)
            paper.clear_cache()  # the paper stages' shared simulations are no longer needed
            return nonlinear
        if name == "rod-length study":
            return agreement.rod_length_study(profile, out_dir, workers, engine, integrator)
        if not figures:
            return []
        if rendering or drawing:  # started beside the stages
            return _figures(out_dir, state, profile, rendering, drawing, engine)
        return _figures(out_dir, state, profile, engine=engine)

    def write_partial() -> None:
        """``results.json`` of the stages in ``done`` (saved with their pickles), partial."""
        nonlocal engine_record
        kept = {k: state[k] for k in done}
        partial = _results(profile, kept, {k: timings[k] for k in done}, workers, t0,
                           model_files, environment, seen)  # fmt: skip
        engine_record = engine_record or _engine_record(engine, integrator, model_files)
        partial.update(engine=engine_record)
        partial.update(partial=True, stages_done=list(done), stages_reused=list(reused))
        write_json(partial, out_dir / "results.json")

    try:
        for name in STAGES:
            if interrupted is not None and interrupted():
                # a signal arrived but its KeyboardInterrupt was lost on the way (caught by
                # a library, or raised in a callback whose exceptions are only printed):
                # stop before the next stage all the same
                raise KeyboardInterrupt
            bar.set_postfix_str(name)
            t = time.perf_counter()
            inputs = file_inputs if name in MODEL_FILE_STAGES else {}
            # the figures draw every stage: redrawn when any stage was recomputed here
            stale = name == "figures" and len(reused) < len(done)
            saved = store.load(name, inputs) if resume and not stale else None
            if saved is not None:
                state[name], timings[name] = saved["value"], saved["seconds"]
                reused.append(name)
            else:
                c = _cpu_seconds()
                state[name] = compute(name)
                timings[name] = round(time.perf_counter() - t, 2)
                cpu[name] = round(_cpu_seconds() - c, 2)
                store.save(name, {"value": state[name], "seconds": timings[name],
                                  "inputs": inputs})  # fmt: skip
            done.append(name)
            # each paper figure drawn as soon as the stages it draws have finished
            ready = ready_paper_figures(done, sent) if worker else []
            if ready:
                drawing = start_paper_figures(out_dir, state, worker, ready, engine) or drawing
                sent.extend(ready)
            if worker and name == "rod-length study":
                drawing = worker
                _send_figure_job(drawing, out_dir, "rod", {"rod_ds": state[name][2]})
            bar.update(1)
            write_partial()
            if on_stage:
                on_stage(name, timings[name], name in reused)
    except KeyboardInterrupt:
        bar.close()
        # the signal may have come between a stage's pickle and the results file: the
        # file then names every stage kept (those a --resume reuses), as the message does
        write_partial()
        raise RunInterrupted(list(done), out_dir) from None
    except (ParameterError, WriteError):  # bad input or an unwritable output: not a crash
        bar.close()
        raise
    except Exception as exc:  # the engine crashed inside a stage: keep what finished
        bar.close()
        if interrupted is not None and interrupted():  # the interrupt, in another guise
            write_partial()
            raise RunInterrupted(list(done), out_dir) from exc
        _write_crash(out_dir, name, exc, _results(profile, state, timings, workers, t0,
                                                  model_files, environment, seen),
                     done, reused)  # fmt: skip
        raise StageCrashed(name, f"{type(exc).__name__}: {exc}", list(done), out_dir) from exc
    except BaseException:
        bar.close()  # an error message then starts on its own line
        raise
    finally:
        blas.close()
        stop_clips(rendering or [])  # the figures stage was reused, or the run stopped
        stop_paper_figures(drawing or worker)
    bar.close()
    results = _results(profile, state, timings, workers, t0, model_files, environment, seen)
    results.update(engine=engine_record or _engine_record(engine, integrator, model_files))
    results.update(partial=False, stages_done=list(done), stages_reused=list(reused))
    results.update(cpu_s=dict(cpu))
    return results


def _cpu_seconds() -> float:
    """CPU seconds (user + system) of this process's threads and its reaped children.

    Less sensitive to a shared machine's load than the wall time; a process pool's
    workers count once they have been reaped.
    """
    import resource

    ch = resource.getrusage(resource.RUSAGE_CHILDREN)
    return time.process_time() + ch.ru_utime + ch.ru_stime


def _write_crash(out_dir: Path, stage: str, exc: BaseException, partial: dict,
                 done: list[str], reused: list[str]) -> None:  # fmt: skip
    """``results.json`` of the finished stages, partial, naming the stage that crashed."""
    import traceback

    tb = "".join(traceback.format_exception(exc)[-6:])
    partial.update(partial=True, stages_done=list(done), stages_reused=list(reused),
                   crashed={"stage": stage, "error": f"{type(exc).__name__}: {exc}",
                            "traceback": tb})  # fmt: skip
    write_json(partial, out_dir / "results.json")


def _engine_record(
    engine: str, integrator: str | None, files: dict[str, str] | None = None
) -> dict[str, Any]:
    """What ran: the engine, its capabilities and tolerances, the integrator per model."""
    from cip.mjcf_params import read_mapping

    eng = agreement.rigid_engine(engine)
    ran = {
        m: read_mapping(agreement.model_file(m, files, integrator)).integrator
        if eng.integrators else eng.capabilities.integrator
        for m in PAPER_BETA
    }  # fmt: skip
    tolerance = {m: eng.twin_tolerance_for(m) for m in PAPER_BETA}
    return {"name": engine, "integrator_requested": integrator, "integrator": ran,
            "capabilities": eng.capabilities.as_dict(), "twin_tolerance": tolerance,
            "rod_tolerance": eng.rod_tolerance}  # fmt: skip


#: the stage that computes each datum of the paper figures (keyword arguments of
#: :func:`validation.report.plots.paper_figures`; which figure draws which:
#: :data:`validation.report.figures.PAPER_FIGURES`)
FIGURE_DATA_STAGES = {"lyapunov_points": "lambda1 agreement", "series": "time-series agreement",
                      "scan": "amplitude scan", "bstar": "critical gains",
                      "curve": "lambda1 curve", "rms": "RMS and velocity",
                      "peaks": "STCC and spectra"}  # fmt: skip


def _paper_figure_data(state: dict[str, Any], keys: Any = None, engine: str = "mujoco"
                       ) -> dict[str, Any]:  # fmt: skip
    """The keyword arguments ``keys`` (default all) of
    :func:`validation.report.plots.paper_figures` from the stages, and the label of the
    registered ``engine``'s data (its family, e.g. "Drake")."""
    keys = FIGURE_DATA_STAGES if keys is None else keys
    get = {"lyapunov_points": lambda: state["lambda1 agreement"][1]["lyapunov"],
           "series": lambda: state["time-series agreement"][1],
           "scan": lambda: state["amplitude scan"][1],
           "bstar": lambda: state["critical gains"][2],
           "curve": lambda: state["lambda1 curve"],
           "rms": lambda: state["RMS and velocity"][1],
           "peaks": lambda: state["STCC and spectra"][1]}  # fmt: skip
    return {"engine": engine_label(engine), **{k: get[k]() for k in keys}}


def engine_label(engine: str) -> str:
    """How the figures name the registered ``engine``'s data: its family
    (:attr:`cipcore.engine.Capabilities.family`: "MuJoCo", "Drake", ...), else its name."""
    return agreement.rigid_engine(engine).capabilities.family or engine


def ready_paper_figures(done: Any, sent: Any = ()) -> list[str]:
    """The paper figures (file names, report order) not in ``sent`` whose data the
    stages ``done`` have all computed."""
    from validation.report.figures import PAPER_FIGURES

    return [name for name, keys in PAPER_FIGURES.items() if name not in sent
            and all(FIGURE_DATA_STAGES[k] in done for k in keys)]  # fmt: skip


def spawn_figure_worker(out_dir: Path) -> tuple[Any, Path, Any, Any]:
    """Start :mod:`validation.report.figures` (it waits for its job on stdin): (process,
    its job file, its stdout file (the figures' paths), its stderr file)."""
    import subprocess
    import tempfile

    out, err = tempfile.TemporaryFile(mode="w+"), tempfile.TemporaryFile(mode="w+")
    cmd = [sys.executable, "-m", "validation.report.figures"]
    proc = subprocess.Popen(cmd, stdin=subprocess.PIPE, stdout=out, stderr=err, text=True)
    return proc, out_dir / STAGE_DIR / "figures-job.pkl", out, err


def start_paper_figures(
    out_dir: Path, state: dict[str, Any], worker: tuple[Any, Path, Any, Any] | None = None,
    names: list[str] | None = None, engine: str = "mujoco",
) -> tuple[Any, Path, Any, Any]:  # fmt: skip
    """Draw the paper figures ``names`` (default every one) in the child process
    ``worker`` (:func:`spawn_figure_worker`, started here if None) while the later
    stages run; returns it.  Its stdin stays open for further figures and the
    rod-length study's (:func:`finish_paper_figures`)."""
    from validation.report.figures import PAPER_FIGURES

    drawing = worker or spawn_figure_worker(out_dir)
    names = list(PAPER_FIGURES) if names is None else list(names)
    keys = sorted({k for name in names for k in PAPER_FIGURES[name]})
    _send_figure_job(drawing, out_dir, "paper",
                     {"only": names, **_paper_figure_data(state, keys, engine)})  # fmt: skip
    return drawing


def _figure_job_files(job: Path) -> list[Path]:
    """The figure worker's job files not yet read (it removes each once read)."""
    return sorted(job.parent.glob("figures-*job.pkl"))


def _send_figure_job(
    drawing: tuple[Any, Path, Any, Any], out_dir: Path, kind: str, kwargs: dict
) -> None:
    """One job for the figure worker (:mod:`validation.report.figures`): its pickle, in a
    file of its own (the worker may still be reading the previous one), then its path on
    the worker's stdin."""
    proc, job, _, _ = drawing
    job.parent.mkdir(parents=True, exist_ok=True)
    fd, name = tempfile.mkstemp(prefix=f"figures-{kind}-", suffix="-job.pkl", dir=job.parent)
    os.close(fd)
    path = Path(name)
    _atomic(path, pickle.dumps({"out_dir": str(out_dir), "kind": kind, "kwargs": kwargs},
                               protocol=pickle.HIGHEST_PROTOCOL))  # fmt: skip
    try:
        proc.stdin.write(f"{path}\n")
        proc.stdin.flush()
    except OSError:  # the worker died early: finish_paper_figures reports why
        pass


def stop_paper_figures(drawing: tuple[Any, Path, Any, Any] | None) -> None:
    """End a figure worker still running (its figures are left out); remove its job file."""
    if drawing is None:
        return
    proc, job, out, err = drawing
    if proc.poll() is None:
        proc.kill()
        proc.wait()
    if proc.stdin and not proc.stdin.closed:
        try:
            proc.stdin.close()
        except OSError:
            pass
    out.close()
    err.close()
    for path in _figure_job_files(job):
        path.unlink(missing_ok=True)


def finish_paper_figures(
    drawing: tuple[Any, Path, Any, Any], out_dir: Path | None = None, rod_ds: Any = None
) -> list[Path]:
    """The figures the :func:`start_paper_figures` process drew, and the rod-length
    study's (dataset ``rod_ds``, drawn into ``out_dir``) where given; raises if it
    failed."""
    proc, job, out, err = drawing
    if rod_ds is not None and out_dir is not None:
        _send_figure_job(drawing, out_dir, "rod", {"rod_ds": rod_ds})
    try:
        proc.stdin.close()
    except OSError:
        pass
    proc.wait()
    for path in _figure_job_files(job):
        path.unlink(missing_ok=True)
    from validation.report.figures import PAPER_FIGURES, WRITE_ERROR, WRITE_ERROR_STATUS

    if proc.returncode != 0:
        err.seek(0)
        why = (err.read().strip().splitlines() or ["no output"])[-1]
        if proc.returncode == WRITE_ERROR_STATUS and why.startswith(WRITE_ERROR):
            raise WriteError(*json.loads(why.removeprefix(WRITE_ERROR)))  # a full disk: exit 2
        raise RuntimeError(f"drawing the figures failed: {why}")

    out.seek(0)
    files = [Path(line) for line in out.read().splitlines() if line.strip()]
    order = {name: k for k, name in enumerate(PAPER_FIGURES)}  # the report's order
    return sorted(files, key=lambda f: order.get(f.name, len(order)))


def _figures(
    out_dir: Path, state: dict[str, Any], profile: Profile,
    rendering: list[tuple[Path, Any, Any]] | None = None,
    drawing: tuple[Any, Path, Any, Any] | None = None, engine: str = "mujoco",
) -> list[Path]:  # fmt: skip
    """Every figure and clip; ``rendering`` and ``drawing``: the clips' and the figures'
    processes where already started (else the figures are drawn here).  The figure
    process draws the rod-length study's figures too, after the paper's."""
    from validation.report.figures import rod_figures

    _, _, rod_ds = state["rod-length study"]
    if rendering is None:  # child processes, rendering while the figures are drawn
        rendering = start_clips(out_dir, profile)
    try:
        if drawing is None:
            # matplotlib: imported by runs that draw figures only
            from validation.report import plots

            files = plots.paper_figures(out_dir, _paper_figure_data(state, engine=engine))
            files += rod_figures(out_dir, rod_ds)
        else:  # drawn beside the last stages, in the order above (both jobs sent)
            files = finish_paper_figures(drawing)
    except BaseException:
        stop_clips(rendering)
        raise
    return files + finish_clips(rendering)


def clips(out_dir: Path, profile: Profile) -> list[Path]:
    """GIFs of a coupled MuJoCo run inside and one leaving the small-angle regime.

    Each is ``cip-validate render`` in a child process (offscreen OpenGL must
    be chosen before MuJoCo is imported, which this process has done), with
    the profile's seed and the paper's coupled gain; the two render at the
    same time.  Where no offscreen OpenGL exists the clips are left out with
    the reason on stderr; the run goes on.
    """
    return finish_clips(start_clips(out_dir, profile))


def start_clips(out_dir: Path, profile: Profile) -> list[tuple[Path, Any, Any]]:
    """Start the :func:`clips` child processes: (path, process, its stderr file) each."""
    import subprocess
    import tempfile

    if profile.clip_duration <= 0:
        return []
    env = {**os.environ, "MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl")}
    out = []
    for label, amp in zip(("inside", "outside"), profile.clip_amplitudes, strict=True):
        path = out_dir / f"clip_{label}_small_angle.gif"
        cmd = [sys.executable, "-m", "validation.cli.main", "render", "--engine", "mujoco",
               "--model", "coupled", "--beta", str(PAPER_BETA["coupled"]),
               "--amplitude", str(amp), "--duration", str(profile.clip_duration),
               "--seed", str(profile.seed), "--fps", "15", "--width", "640", "--height",
               "400", "--out", str(path)]  # fmt: skip
        err = tempfile.TemporaryFile(mode="w+")  # read once the process has ended
        proc = subprocess.Popen(cmd, env=env, stdout=subprocess.DEVNULL, stderr=err)
        out.append((path, proc, err))
    return out


def stop_clips(rendering: list[tuple[Path, Any, Any]]) -> None:
    """End the :func:`start_clips` processes still running (their files are left out)."""
    for _, proc, err_file in rendering:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        err_file.close()


def finish_clips(rendering: list[tuple[Path, Any, Any]]) -> list[Path]:
    """Wait for the :func:`start_clips` processes; the clips made, in order."""
    out = []
    for path, proc, err_file in rendering:
        proc.wait()
        with err_file as f:
            f.seek(0)
            err = f.read()
        if proc.returncode != 0 or not path.exists():
            why = (err.strip().splitlines() or ["no output"])[-1]
            print(f"cip-validate: clip {path.name} left out: {why}", file=sys.stderr)
            continue
        out.append(path)
    return out


#: the stages whose runs are searched for divergence, in the order ``results.json`` lists them
DIVERGENCE_STAGES = ("time-series agreement", "amplitude scan", "RMS and velocity",
                     "rod-length study", "lambda1 agreement")  # fmt: skip


def _divergence(state: dict[str, Any], seen: dict[str, tuple] | None = None) -> list[dict]:
    """Where runs of the finished stages diverged or left the small-angle regime.

    Time series at the paper's gains (both engines, every realisation), the
    amplitude scan (whose large amplitudes leave the small angles on purpose),
    the RMS runs, the rod-length study (per grid point) and the engine's lambda1 runs
    (a Benettin run whose state went non-finite).  ``seen`` (stage name ->
    (its value, its rows)) keeps each stage's rows across the calls of one run: the
    partial ``results.json`` written after every stage searches a stage's trajectories
    once, not once per later stage (0.05 s a call for the quick profile's time series).
    """
    out: list[dict] = []
    for name in DIVERGENCE_STAGES:
        if name not in state:
            continue
        if seen is not None and name in seen and seen[name][0] is state[name]:
            out += seen[name][1]
            continue
        rows = _stage_divergence(name, state[name])
        if seen is not None:
            seen[name] = (state[name], rows)
        out += rows
    return out


def _stage_divergence(name: str, value: Any) -> list[dict]:
    """:func:`_divergence`'s rows of one stage ``name`` from its value."""
    from validation.checks.divergence import pendulum_length, summary, trajectory_events

    out: list[dict] = []
    if name == "time-series agreement":
        for model, d in value[1].items():
            for side in ("full", "reduced"):
                tr = d[side]
                p = BalanceParams(**{k: tr.attrs[k] for k in
                                     ("beta", "alpha", "gamma", "nu", "tau", "dt")})  # fmt: skip
                ev = trajectory_events(tr, pendulum_length(p))
                line = summary(ev, tr.shape[0])
                if line:
                    out.append({"stage": "time-series agreement", "run": f"{model} {side}",
                                "summary": line, "events": [e.as_dict() for e in ev]})  # fmt: skip
    elif name == "amplitude scan":
        for r in value[1]:
            if r.get("engine_left_regime"):
                out.append({"stage": "amplitude scan", "run": f"{r['model']} amplitude "
                            f"{r['amplitude']:g} m", "summary": "the engine left the small-angle "
                            f"regime (largest |theta| {r['max_abs_angle']:.3g} rad) while the "
                            f"reference stayed inside ({r['reference_max_abs_angle']:.3g} rad): "
                            "not intended"})  # fmt: skip
            elif not r["small_angle"]:
                what = "fell (|theta| > pi/2)" if r["fell"] else "left the small-angle regime"
                out.append({"stage": "amplitude scan", "run": f"{r['model']} amplitude "
                            f"{r['amplitude']:g} m", "summary": f"{what}: largest |theta| "
                            f"{r['max_abs_angle']:.3g} rad (intended: the scan looks for the "
                            "breakdown)", "intended": True})  # fmt: skip
    elif name == "RMS and velocity":
        from validation.checks.divergence import rms_divergence

        p = BalanceParams(beta=1.0)  # L = g / alpha does not depend on the gain
        out += rms_divergence(value[1], pendulum_length(p))
    elif name == "rod-length study":
        ds = value[2]
        if "divergence_time" in ds:
            t = ds["divergence_time"]
            dims = [d for d in t.dims if d != "realization"]
            for idx in np.ndindex(*(ds.sizes[d] for d in dims)):
                times = t.isel(dict(zip(dims, idx, strict=True))).values
                bad = np.flatnonzero(np.isfinite(times))
                if bad.size:
                    where = ", ".join(
                        f"{d}={ds[d].values[i]}" for d, i in zip(dims, idx, strict=True)
                    )
                    out.append({"stage": "rod-length study", "run": where,
                                "summary": f"realisations {bad.tolist()} of {times.size} "
                                f"diverged (first at t = {np.nanmin(times):.4g} s)"})  # fmt: skip
    elif name == "lambda1 agreement":
        for row in value[1]["lyapunov"]:
            at = row["full"].get("diverged_at")
            if at is not None:
                bad = [k for k, t in enumerate(at) if t is not None]
                out.append({"stage": "lambda1 agreement",
                            "run": f"{row['model']} beta {row['beta']:g} engine",
                            "summary": f"realisations {bad} of {len(at)} went non-finite "
                            f"(first by t = {min(at[k] for k in bad):.4g} s; Benettin run, "
                            "their exponents +inf)"})  # fmt: skip
    return out


def _results(
    profile: Profile,
    state: dict[str, Any],
    timings: dict,
    workers: int | None,
    t0: float,
    model_files: dict[str, str] | None,
    environment: dict[str, Any],
    seen: dict[str, tuple] | None = None,
) -> dict[str, Any]:
    """The results dictionary from the stages finished so far (in stage order);
    ``environment``: :func:`validation.cli.ci_options.run_environment` of the run;
    ``seen``: :func:`_divergence`'s rows of the stages already searched."""
    checks, paper_rows = [], []
    scan_rows, rod_rows, figure_files = [], [], []
    robust, nonlinear = None, None
    for name in RESULT_ORDER:
        if name not in state:
            continue
        v = state[name]
        if name == "conformance and anchors":
            checks += v
        elif name in ("lambda1 agreement", "time-series agreement"):
            checks += v[0]
        elif name == "amplitude scan":
            checks += v[0]
            scan_rows = v[1]
        elif name == "critical gains":
            checks += v[0]
            paper_rows += v[1]
        elif name in ("RMS and velocity", "STCC and spectra"):
            paper_rows += v[0]
        elif name == "robustness":
            robust = v
        elif name == "nonlinear stick":
            nonlinear = v
        elif name == "rod-length study":
            checks += v[0]
            rod_rows = v[1]
        elif name == "figures":
            figure_files = v
    divergence = _divergence(state, seen)
    counts = {s: sum(ch.status == s for ch in checks) for s in (PASS, FAIL, INCONCLUSIVE)}
    if any(ch.status == NOT_APPLICABLE for ch in checks):  # a tier's checks that do not judge
        counts[NOT_APPLICABLE] = sum(ch.status == NOT_APPLICABLE for ch in checks)
    return {
        "cipval_results": 1,
        "profile": profile.name,
        "settings": profile.as_dict(),
        "status": FAIL if counts[FAIL] else (INCONCLUSIVE if counts[INCONCLUSIVE] else PASS),
        "counts": counts,
        "checks": [with_limit(ch.as_dict()) for ch in checks],
        "paper": paper_rows,
        "robustness": robust,
        "nonlinear": nonlinear,
        "amplitude_scan": scan_rows,
        "rod_length": rod_rows,
        "figures": [str(Path(p).name) for p in figure_files],
        "divergence": divergence,
        **environment,  # versions, platform, fingerprint
        "model_files": {k: str(v) for k, v in (model_files or {}).items()},
        "workers": workers,
        "timings_s": dict(timings),
        "elapsed_s": round(time.perf_counter() - t0, 1),
    }
