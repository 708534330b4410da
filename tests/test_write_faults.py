"""Every writer under faults (issue 42, item 4): the n-th write of a command fails.

A :class:`helpers.WriteFault` makes the n-th write operation on a chosen output fail
(``open``, a ``write()`` that puts half its data on disk first, ``fsync``, the rename onto
the final name) with ENOSPC, EIO or EACCES, in this process and, through a
``sitecustomize`` on ``PYTHONPATH``, in every Python child the command starts (the run's
figure worker, ``render``'s fresh process).  For every writer of :data:`WRITERS` (name ->
the command that runs it and the file it writes) the test proves:

* the final name holds the complete old file (or nothing, where there was none): never a
  part, and every other file the command left is whole (:func:`complete`);
* no temporary file is left anywhere;
* the command exits 2 (``validation/cli/exitcodes.py``: an output that cannot be written is
  bad input) with one line ``cip-validate: error: ...`` naming the file, and no traceback.

:func:`test_every_write_call_is_a_listed_writer` reads the source tree (every call that
writes a file: ``open`` for writing, ``write_text``, ``savefig``, ``np.savez``,
``to_netcdf``, ``os.replace``, ...) and fails on a call site that no writer lists and
:data:`NOT_OUTPUTS` does not explain, so a new writer cannot escape.
"""

from __future__ import annotations

import ast
import errno
import fnmatch
import json
import os
import pickle
import shutil
import zipfile
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import pytest
from helpers import WRITE_FAULT_ENV, WriteFault, final_path, write_fault_site

from cipcore.atomic import WriteError, write_text
from validation.cli.main import main
from validation.profiles import PROFILES
from validation.run import STAGES


def _stage_record(name: str) -> str:
    """A stage's record under the run's directory (its index in the run order)."""
    return f"run/stages/{STAGES.index(name)}-{name.replace(' ', '_')}.pkl"


ROOT = Path(__file__).resolve().parent.parent
#: the packages whose writes are cipval's outputs (benchmarks/ and examples/ are not)
PACKAGES = ("cipcore", "cip", "reduced", "validation")

#: a run of the smoke profile's code paths at a few seconds' sizes (the write paths are
#: what is tested here, not the numbers)
TINY = replace(
    PROFILES["smoke"], lyapunov_duration=5.0, lyapunov_realizations=2, series_duration=12.0,
    series_realizations=2, scan_duration=4.0, scan_realizations=2, beta_star_duration=20.0,
    beta_star_realizations=2, beta_star_gains=3, rms_duration=10.0, rms_realizations=2,
    peak_duration=12.0, peak_realizations=2, spectrum_duration=12.0, spectrum_realizations=2,
    nonlinear_duration=5.0, n_bootstrap=10,
    robustness_grid={"window": (2.5,), "dominance": (0.5,), "half_width": (0.1,),
                     "segment": (5.0,), "threshold": (0.01,)},
    rod_study={"duration": 7.0, "realizations": 2,
               "grid": {"amplitude": [0.001], "rod_length_ratio": [0.2, 2.0]}},
)  # fmt: skip

RUN = ("run", "--profile", "smoke", "--no-figures", "--quiet", "--resume", "--out", "{t}/run",
       "--junit", "{t}/run/j.xml")  # fmt: skip
SWEEP = ("sweep", "--engine", "reduced", "--grid", "beta=20,21", "--metrics", "rms",
         "--duration", "2", "--realizations", "2", "--workers", "1", "--out", "{t}/sw")  # fmt: skip
STABILITY = ("stability", "--beta", "30", "--beta-grid", "0:80:2", "--tau-grid", "0.05:0.2:2",
             "--plot")  # fmt: skip


@dataclass(frozen=True)
class Writer:
    """One output and how to make a command write it.

    ``sites``: the write calls it runs (``path::function::call``, as
    :func:`write_sites` names them); ``argv``: the command (``{t}`` the test's
    directory), empty where a test of its own (``test``) triggers it; ``target``: the
    faulted file (a glob under ``{t}``); ``source``: a fixture whose directory is copied
    into ``{t}`` first (inputs, a finished run); ``old``: run the command once without a
    fault first, so that a complete old file lies under the final name; ``nth``: which
    matching write fails; ``drop``: files removed from the copy (a stage recomputed).
    """

    sites: tuple[str, ...]
    argv: tuple[str, ...] = ()
    target: str = ""
    source: str = ""
    old: bool = True
    nth: int = 1
    drop: tuple[str, ...] = ()
    test: str = "test_a_failed_write_leaves_the_old_file_and_one_line"


#: every output cipval writes: name -> how it is written and triggered
WRITERS: dict[str, Writer] = {
    "simulate: trajectory .npz": Writer(
        ("cipcore/schema.py::Trajectory.save_npz::atomic_path",
         "cipcore/schema.py::Trajectory.save_npz::open",
         "cipcore/schema.py::Trajectory.save_npz::savez"),
        ("simulate", "--beta", "20", "--duration", "1", "--out", "{t}/r.npz"), "r.npz"),
    "stability: region figure (PNG)": Writer(
        ("validation/report/plots.py::plot_stability_region::write_with",
         "validation/report/plots.py::plot_stability_region::savefig"),
        (*STABILITY, "{t}/region.png"), "region.png"),
    "stability: region figure (SVG)": Writer(
        ("validation/report/plots.py::plot_stability_region::savefig",),
        (*STABILITY, "{t}/region.svg"), "region.svg"),
    "baseline --from": Writer(
        ("validation/cli/commands/suite.py::cmd_baseline::write_bytes",),
        ("baseline", "--from", "{t}/run/results.json", "--out", "{t}/b.json"), "b.json",
        source="tiny_run"),
    "run: results.json, the last of its 13 writes": Writer(
        ("validation/report/document.py::write_json::write_text",
         "validation/report/document.py::write_reports::write_json"),
        RUN, "run/results.json", source="tiny_run", old=False, nth=13),
    "run: results.json after the first stage": Writer(
        ("validation/run.py::run_validation::write_partial",
         "validation/run.py::run_validation.write_partial::write_json"),
        RUN, "run/results.json", source="tiny_run", old=False),
    "run: results.json of a crashed run": Writer(
        ("validation/run.py::_write_crash::write_json",),
        test="test_a_crashed_run_whose_results_cannot_be_written"),
    "baseline (a run of its own)": Writer(
        ("validation/cli/commands/suite.py::cmd_baseline::write_json",),
        test="test_a_baseline_of_its_own_run_under_a_fault"),
    "sweep: critical-gain JSON (DIR/gains)": Writer(
        ("validation/sweeps/gains.py::point_gains::atomic_write",),
        ("sweep", "{t}/g.toml", "--workers", "1", "--out", "{t}/gsw"), "gsw/gains/*.json",
        source="gain_study", old=False),
    "run: report.md": Writer(
        ("validation/report/document.py::write_reports::write_text",),
        RUN, "run/report.md", source="tiny_run"),
    "run: report.html": Writer(
        ("validation/report/document.py::write_reports::write_text",),
        RUN, "run/report.html", source="tiny_run"),
    "run: JUnit XML": Writer(
        ("validation/cli/junit.py::write_junit::write_with",
         "validation/cli/junit.py::write_junit::write"),
        RUN, "run/j.xml", source="tiny_run"),
    "run: a stage record": Writer(
        ("validation/run.py::_Stages.save::_atomic", "validation/run.py::_atomic::write_bytes",
         "validation/run.py::run_validation::save"),
        RUN, _stage_record("lambda1 curve"), source="tiny_run", old=False,
        drop=(_stage_record("lambda1 curve"),)),
    "run: the stages' manifest": Writer(
        ("validation/run.py::_Stages.__init__::_atomic",),
        tuple(a for a in RUN if a != "--resume"), "run/stages/manifest.json", source="tiny_run",
        old=False),
    "run: the rod-length study (sweep points)": Writer(
        ("validation/checks/agreement.py::rod_length_study::run_sweep",),
        RUN, "run/rod_length/points/*.json", source="tiny_run", old=False,
        drop=(_stage_record("rod-length study"), "run/rod_length")),
    "sweep: a point (the second)": Writer(
        ("validation/sweeps/store.py::atomic_write::write_text",
         "validation/sweeps/store.py::Store.save::atomic_write",
         "validation/sweeps/schedule.py::run_sweep.finished::save",
         "validation/cli/commands/sweeping.py::cmd_sweep::run_sweep"),
        SWEEP, "sw/points/*.json", old=False, nth=2),
    "sweep: study.json": Writer(
        ("validation/sweeps/store.py::Store.__init__::atomic_write",),
        SWEEP, "sw/study.json", old=False),
    "sweep: dataset sweep.nc": Writer(
        ("validation/sweeps/store.py::write_dataset::write_with",
         "validation/sweeps/store.py::write_dataset::to_netcdf"),
        SWEEP, "sw/sweep.nc"),
    "sweep: report.md": Writer(
        ("validation/sweeps/report.py::write_sweep_report::write_text",),
        SWEEP, "sw/report.md"),
    "sweep: its figure": Writer(
        ("validation/sweeps/report.py::plot_metric::write_with",
         "validation/sweeps/report.py::plot_metric::savefig"),
        SWEEP, "sw/sweep_rms.png"),
    "sweep-plot": Writer(
        ("validation/sweeps/report.py::plot_metric::savefig",),
        ("sweep-plot", "{t}/sw/sweep.nc", "--metric", "rms", "--x", "beta", "--out",
         "{t}/p.png"), "p.png", source="sweep_dir"),
    "sweep-export: CSV": Writer(
        ("validation/cli/commands/sweeping.py::cmd_sweep_export::write_text",
         "validation/cli/commands/sweeping.py::cmd_sweep_export::to_csv"),
        ("sweep-export", "{t}/sw/sweep.nc", "--csv", "{t}/x.csv"), "x.csv", source="sweep_dir"),
    "case export: case file": Writer(
        ("validation/exchange/case.py::export_case::atomic_path",
         "validation/exchange/case.py::export_case::open",
         "validation/exchange/case.py::export_case::savez"),
        ("case", "export", "--realizations", "2", "--out", "{t}/c.npz"), "c.npz"),
    "case run: trajectories file": Writer(
        ("validation/cli/commands/case.py::cmd_run::atomic_path",
         "validation/cli/commands/case.py::cmd_run::open",
         "validation/cli/commands/case.py::cmd_run::savez"),
        ("case", "run", "--case", "{t}/case/c.npz", "--out", "{t}/t.npz"), "t.npz",
        source="case_files"),
    "case check: JUnit XML": Writer(
        ("validation/cli/junit.py::write_junit::write_with",),
        ("case", "check", "--case", "{t}/case/c.npz", "--trajectories", "{t}/case/t.npz",
         "--junit", "{t}/j.xml", "--quiet"), "j.xml", source="case_files"),
    "engines: results.json": Writer(
        ("validation/engines.py::write_engine_reports::write_json",),
        ("engines", "--engines", "reduced", "--profile", "smoke", "--quiet", "--out",
         "{t}/eng"), "eng/results.json", old=False),
    "engines: report.md and report.html": Writer(
        ("validation/engines.py::write_engine_reports::write_text",),
        ("engines", "--engines", "reduced", "--profile", "smoke", "--quiet", "--out",
         "{t}/eng"), "eng/report.html", old=False),
    "engines: speed-accuracy figure": Writer(
        ("validation/engines.py::speed_accuracy_figure::write_with",
         "validation/engines.py::speed_accuracy_figure::savefig"),
        test="test_the_engines_figure_and_the_model_files_under_a_fault"),
    "model files (cip.model.write_models)": Writer(
        ("cip/model.py::write_models::write_text",),
        test="test_the_engines_figure_and_the_model_files_under_a_fault"),
    "run: paper figures (the figure worker)": Writer(
        ("validation/report/plots.py::_save::write_with",
         "validation/report/plots.py::_save::savefig",
         "validation/run.py::_send_figure_job::_atomic"),
        test="test_a_figure_the_worker_cannot_write_is_a_write_error"),
    "render: GIF clip": Writer(
        ("validation/report/animation.py::write_video::write_with",
         "validation/report/animation.py::write_video::save",
         "validation/report/animation.py::write_video::atomic_path",
         "validation/report/animation.py::write_video::saving"),
        ("render", "--model", "coupled", "--beta", "21.032", "--amplitude", "0.05",
         "--duration", "0.2", "--fps", "10", "--width", "64", "--height", "48", "--out",
         "{t}/c.gif"), "c.gif", old=False,
        test="test_a_clip_that_cannot_be_written"),
    "experiment bots: recording .npz": Writer(
        ("validation/experiment/recording.py::write_npz::atomic_path",
         "validation/experiment/recording.py::write_npz::open",
         "validation/experiment/recording.py::write_npz::savez"),
        ("experiment", "bots", "--out", "{t}/bots", "--mode", "single", "--trials", "1",
         "--trial-duration", "1"), "bots/*.npz", old=False),
    "experiment bots: recording log .jsonl (append-only)": Writer(
        ("validation/experiment/recording.py::Recorder.__init__::open",
         "validation/experiment/recording.py::Recorder._write::write",
         "validation/experiment/recording.py::Recorder.event::write"),
        test="test_a_recording_log_that_cannot_be_written"),
    "experiment analyze: results.json": Writer(
        ("validation/experiment/report.py::write_report::write_text",),
        ("experiment", "analyze", "{t}/bots", "--out", "{t}/ana"), "ana/results.json",
        source="recordings"),
    "experiment analyze: a figure": Writer(
        ("validation/experiment/report.py::_save::write_with",
         "validation/experiment/report.py::_save::savefig"),
        ("experiment", "analyze", "{t}/bots", "--out", "{t}/ana"), "ana/move_s.png",
        source="recordings"),
}  # fmt: skip

#: write calls that make no output of a command, and why
NOT_OUTPUTS: dict[str, str] = {
    "cipcore/atomic.py::atomic_path::replace": "the atomic writer itself",
    "cipcore/atomic.py::write_with::atomic_path": "the atomic writer itself",
    "cipcore/atomic.py::write_bytes::write_with": "the atomic writer itself",
    "cipcore/atomic.py::write_bytes::write_bytes": "the atomic writer itself (the temporary)",
    "cipcore/atomic.py::write_text::write_with": "the atomic writer itself",
    "cipcore/atomic.py::write_text::write_text": "the atomic writer itself (the temporary)",
    "cip/engines/mjx.py::_exported_chunk::write_bytes": "MJX's compile cache, through "
    "cipcore.atomic; a write error leaves no cache, by design (needs JAX to reach)",
    "cip/engines/process.py::_write::write": "the engine's stdin (a pipe)",
    "cip/engines/process.py::_drain_stderr::write": "the engine's stderr passed on to ours",
    "cip/quiet.py::quiet_import::open": "/dev/null",
    "validation/cli/args.py::_probe::mkstemp": "the writability probe of --out (removed)",
    "validation/cli/commands/suite.py::_say::write": "the terminal (tqdm.write)",
    "validation/run.py::_note::write": "the terminal (tqdm.write)",
    "validation/sweeps/store.py::_note::write": "the terminal (tqdm.write)",
    "validation/sweeps/store.py::DirectoryLock.__init__::open": "the sweep's lock file "
    "(empty; locked with flock, never read for data)",
    "validation/run.py::spawn_figure_worker::TemporaryFile": "an anonymous temporary file",
    "validation/run.py::start_clips::TemporaryFile": "an anonymous temporary file",
    "validation/run.py::_send_figure_job::mkstemp": "the figure worker's job (removed once read)",
    "validation/run.py::_send_figure_job::write": "the figure worker's stdin (a pipe)",
    "validation/cli/commands/suite.py::cmd_baseline::TemporaryDirectory": "the run's stages "
    "of `baseline` (removed)",
    "validation/faults/file.py::write_edited::write": "a faulted model file of selftest, in a "
    "temporary directory",
    "validation/faults/file.py::flagged_by_file::TemporaryDirectory": "selftest's model files",
    "validation/faults/file.py::flagged_by_file::write": "selftest's model files (a "
    "temporary directory)",
    "validation/faults/file.py::flagged_by_conformance::write": "selftest's model files (a "
    "temporary directory)",
    "validation/faults/file.py::equivalent_failures::TemporaryDirectory": "selftest's files",
    "validation/faults/file.py::flagged_by_conformance::TemporaryDirectory": "selftest's files",
    "validation/experiment/finalize.py::NpzWriter.write::write": "the .npz worker's stdin",
    "validation/experiment/finalize.py::finalize::write": "NpzWriter.write (a pipe)",
    "validation/experiment/cli.py::cmd_serve::FileHandler": "the server's log (append-only)",
}

#: the calls that write a file (or name one for writing); ``open``-like calls count when
#: their mode writes
WRITE_CALLS = {
    "write_text", "write_bytes", "write_with", "atomic_path", "savefig", "save", "savez",
    "savez_compressed", "savetxt", "dump", "to_netcdf", "to_zarr", "to_csv", "to_parquet",
    "tofile", "replace", "rename", "copy", "copy2", "copyfile", "copytree", "move", "write",
    "writelines", "imsave", "imwrite", "mkstemp", "NamedTemporaryFile", "TemporaryFile",
    "TemporaryDirectory", "saving", "FileHandler", "open", "_atomic", "atomic_write",
    "write_json", "write_partial", "run_sweep",
}  # fmt: skip
#: receivers of ``.replace`` / ``.copy`` / ``.save``... that are not files
NOT_FILE_RECEIVERS = ("str", "copy", "dataclasses")
KINDS = {
    "ENOSPC mid-write": ("write", errno.ENOSPC),
    "EIO at fsync": ("fsync", errno.EIO),
    "EACCES at the rename": ("replace", errno.EACCES),
}


# ------------------------------------------------------------------- the meta-test
def _writes(call: ast.Call, name: str) -> bool:
    """Whether a call named ``name`` writes a file (modes and flags read where stated)."""
    if name == "open":
        mode = call.args[1] if len(call.args) > 1 else None
        mode = next((k.value for k in call.keywords if k.arg == "mode"), mode)
        if isinstance(call.func, ast.Attribute) and call.func.attr == "open":
            owner = ast.unparse(call.func.value)
            if owner == "os":  # flags: O_WRONLY, O_RDWR, O_CREAT
                return any(f in ast.unparse(call.args[1]) for f in ("O_WR", "O_RDWR", "O_CREAT"))
        return isinstance(mode, ast.Constant) and bool(set(str(mode.value)) & set("wax+"))
    if name == "dump":  # json.dump(obj, file); a one-argument dump returns text
        return len(call.args) >= 2
    if name in ("replace", "copy"):
        return isinstance(call.func, ast.Attribute) and ast.unparse(call.func.value) in (
            "os", "shutil")  # fmt: skip
    return True


class _WriteCalls(ast.NodeVisitor):
    """Collects ``path::function::call`` of the write calls of one module."""

    def __init__(self, rel: str) -> None:
        self.rel, self.stack, self.sites = rel, [], set()

    def visit_FunctionDef(self, node: ast.AST) -> None:
        self.stack.append(node.name)
        self.generic_visit(node)
        self.stack.pop()

    visit_AsyncFunctionDef = visit_ClassDef = visit_FunctionDef

    def visit_Call(self, node: ast.Call) -> None:
        f = node.func
        name = f.attr if isinstance(f, ast.Attribute) else getattr(f, "id", None)
        if name in WRITE_CALLS and _writes(node, name):
            self.sites.add(f"{self.rel}::{'.'.join(self.stack) or '<module>'}::{name}")
        self.generic_visit(node)


def write_sites(roots: tuple[str, ...] = PACKAGES) -> set[str]:
    """``path::function::call`` of every call in ``roots`` that writes a file."""
    sites: set[str] = set()
    for root in roots:
        for path in sorted((ROOT / root).rglob("*.py")):
            visitor = _WriteCalls(path.relative_to(ROOT).as_posix())
            visitor.visit(ast.parse(path.read_text()))
            sites |= visitor.sites
    return sites


def test_every_write_call_is_a_listed_writer():
    """A write call in the packages that no writer lists, and that is not explained as no
    output, fails here: add the writer to WRITERS (how to trigger it) first."""
    found = write_sites()
    listed = {s for w in WRITERS.values() for s in w.sites}
    unlisted = sorted(found - listed - set(NOT_OUTPUTS))
    assert not unlisted, "write calls no writer lists (add them to WRITERS):\n" + "\n".join(
        unlisted
    )
    stale = sorted((listed | set(NOT_OUTPUTS)) - found)
    assert not stale, "listed write calls that no longer exist:\n" + "\n".join(stale)
    tests = {w.test for w in WRITERS.values()}
    assert tests <= set(globals()), tests - set(globals())


# ------------------------------------------------------------------- the checks
def complete(path: Path) -> bool:
    """Whether ``path`` is a whole file of its kind (a cut one fails to parse or lacks
    its end)."""
    data = path.read_bytes()
    kind = path.suffix.lower()
    try:
        if kind == ".json":
            json.loads(data)
        elif kind == ".png":
            return data.startswith(b"\x89PNG") and data.endswith(b"IEND\xaeB`\x82")
        elif kind == ".gif":
            return data.startswith(b"GIF8") and data.endswith(b";")
        elif kind in (".svg", ".xml"):
            import xml.etree.ElementTree as ET

            ET.fromstring(data)
        elif kind == ".html":
            return data.rstrip().endswith(b"</html>")
        elif kind == ".npz":
            with zipfile.ZipFile(path) as z:
                return z.testzip() is None
        elif kind == ".nc":
            _read_netcdf(path)
        elif kind == ".pkl":
            pickle.loads(data)
        elif kind in (".md", ".csv"):
            return data.endswith(b"\n")
    except Exception:
        return False
    return True


def _read_netcdf(path: Path) -> None:
    """Read every variable of a netCDF-3 file (a cut one raises)."""
    from scipy.io import netcdf_file

    with netcdf_file(path, "r", mmap=False) as f:
        for v in f.variables.values():
            np.asarray(v[...]).copy()


def _tree(directory: Path) -> dict[Path, bytes]:
    return {p: p.read_bytes() for p in directory.rglob("*") if p.is_file()}


def _leftovers(directory: Path) -> list[str]:
    """Temporary files a writer left (``.NAME.tmpPID``, ``.npz.part``)."""
    return sorted(p.name for p in directory.rglob("*") if ".tmp" in p.name or
                  p.name.endswith(".part"))  # fmt: skip


def check_outcome(
    code: int, err: str, target: Path, before: dict[Path, bytes], root: Path, exact: bool = True
) -> None:
    """The documented outcome of a failed write (module docstring); ``exact``: the target
    holds the very file it held before (else, a later write failed: a whole one)."""
    assert "Traceback" not in err, err[-3000:]
    lines = [x for x in err.splitlines() if x.startswith("cip-validate: error")]
    assert code == 2 and len(lines) == 1, (code, err[-3000:])
    assert str(target) in lines[0], lines[0]
    assert _leftovers(root) == []
    now = target.read_bytes() if target.exists() else None
    if exact:  # the old file, whole, or nothing where there was none
        assert now == before.get(target), "the old file was not kept (or a new one appeared)"
    elif now is not None:
        assert complete(target), f"{target} is not whole"
    for path, data in _tree(root).items():
        if path.name in ("fault.log", "sitecustomize.py") or "__pycache__" in path.parts:
            continue
        assert before.get(path) == data or complete(path), f"{path} is not whole"


# ------------------------------------------------------------------- fixtures
@pytest.fixture
def tiny_profile(monkeypatch):
    monkeypatch.setitem(PROFILES, "smoke", TINY)


@pytest.fixture(scope="module")
def tiny_run(tmp_path_factory) -> Path:
    """A finished ``run`` of :data:`TINY` in ``DIR/run``, without figures."""
    where = tmp_path_factory.mktemp("tiny")
    with pytest.MonkeyPatch.context() as mp:
        mp.setitem(PROFILES, "smoke", TINY)
        argv = [a.replace("{t}", str(where)) for a in RUN if a != "--resume"]
        assert main(argv) in (0, 1)
    return where


@pytest.fixture(scope="module")
def sweep_dir(tmp_path_factory) -> Path:
    where = tmp_path_factory.mktemp("sweep")
    assert main([a.replace("{t}", str(where)) for a in SWEEP]) == 0
    return where


@pytest.fixture(scope="module")
def gain_study(tmp_path_factory) -> Path:
    """A study file with a [gain] target at a few seconds' sizes (the critical gain)."""
    where = tmp_path_factory.mktemp("gain")
    (where / "g.toml").write_text(
        '[study]\nname = "g"\nengine = "reduced"\nmodel = "single"\nmetrics = ["rms"]\n'
        "realizations = 2\nduration = 10.0\nseed = 1\n\n[gain]\ntarget_lambda1 = 5e-4\n"
        "half_width = 5.0\ngains = 3\nrealizations = 2\nduration = 20.0\n\n"
        "[grid]\ntau = [0.1]\n"
    )
    return where


@pytest.fixture(scope="module")
def case_files(tmp_path_factory) -> Path:
    where = tmp_path_factory.mktemp("case")
    c, t = where / "case" / "c.npz", where / "case" / "t.npz"
    c.parent.mkdir()
    assert main(["case", "export", "--realizations", "2", "--out", str(c)]) == 0
    assert main(["case", "run", "--case", str(c), "--out", str(t)]) == 0
    return where


@pytest.fixture(scope="module")
def recordings(tmp_path_factory) -> Path:
    where = tmp_path_factory.mktemp("rec")
    assert main(["experiment", "bots", "--out", str(where / "bots"), "--mode", "single",
                 "--trials", "1", "--trial-duration", "2"]) == 0  # fmt: skip
    return where


@pytest.fixture
def inject(tmp_path, monkeypatch) -> Callable[..., WriteFault]:
    """``inject(pattern, op, errno, nth)``: the fault, in this process and its children."""

    def install(pattern: str, op: str, code: int, nth: int = 1) -> WriteFault:
        fault = WriteFault(str(pattern), op, code, nth, log=str(tmp_path / "fault.log"))
        site = write_fault_site(tmp_path / "site")
        monkeypatch.setenv(WRITE_FAULT_ENV, fault.to_env())
        monkeypatch.setenv("PYTHONPATH", f"{site}:{ROOT}")
        fault.install(monkeypatch.setattr)
        return fault

    return install


def _hits(tmp_path: Path) -> list[str]:
    log = tmp_path / "fault.log"
    return log.read_text().splitlines() if log.exists() else []


@pytest.fixture(scope="module")
def prepared(request, tmp_path_factory) -> Callable[[str], Path]:
    """``prepared(name)``: a directory holding writer ``name``'s inputs and, where it has
    ``old``, the outputs of one run without a fault (made once, copied by each test)."""
    made: dict[str, Path] = {}

    def prepare(name: str) -> Path:
        if name not in made:
            writer, where = WRITERS[name], tmp_path_factory.mktemp("prepared")
            if writer.source:
                shutil.copytree(request.getfixturevalue(writer.source), where,
                                dirs_exist_ok=True)  # fmt: skip
            for drop in writer.drop:
                p = where / drop
                shutil.rmtree(p) if p.is_dir() else p.unlink()
            if writer.old:
                with pytest.MonkeyPatch.context() as mp:
                    mp.setitem(PROFILES, "smoke", TINY)
                    assert main(_argv(writer, where)) in (0, 1)
            made[name] = where
        return made[name]

    return prepare


def _argv(writer: Writer, tmp_path: Path) -> list[str]:
    return [a.replace("{t}", str(tmp_path)) for a in writer.argv]


def _cases() -> list:
    """Each writer with a failing ``write()`` (the fault that would leave half a file) and,
    by turns, a failing ``fsync`` or rename."""
    names = [name for name, w in WRITERS.items() if w.argv and w.test == Writer.test]
    others = [k for k in KINDS if k != "ENOSPC mid-write"]
    return [pytest.param(name, kind, id=f"{name} / {kind}")
            for i, name in enumerate(names)
            for kind in ("ENOSPC mid-write", others[i % len(others)])]  # fmt: skip


# ------------------------------------------------------------------- the tests
@pytest.mark.parametrize(("name", "kind"), _cases())
def test_a_failed_write_leaves_the_old_file_and_one_line(
    name, kind, prepared, tmp_path, capfd, inject, tiny_profile
):
    writer = WRITERS[name]
    shutil.copytree(prepared(name), tmp_path, dirs_exist_ok=True)
    capfd.readouterr()
    before = _tree(tmp_path)
    op, code = KINDS[kind]
    inject(tmp_path / writer.target, op, code, writer.nth)
    status = main(_argv(writer, tmp_path))
    err = capfd.readouterr().err
    hits = _hits(tmp_path)
    assert len(hits) == 1, f"the fault never happened (or more than once): {hits}"
    target = Path(hits[0].split(" ", 2)[2])
    check_outcome(status, err, target, before, tmp_path, exact=writer.nth == 1)
    assert os.strerror(code) in err


class _FirstWrites(WriteFault):
    """Fails nothing; lists the files written, in the order of their first ``write()``."""

    def hit(self, op: str, path) -> bool:
        name = final_path(path)
        if op == "write" and fnmatch.fnmatch(name, self.pattern) and name not in self.files:
            self.files.append(name)
        return False


def test_the_nth_file_of_a_sweep_for_every_n(tmp_path, capfd):
    """The n-th file the whole command writes, whatever it is, for every n: its first
    ``write()`` fails (ENOSPC) after half its data."""
    clean = tmp_path / "clean"
    order = _FirstWrites(str(clean / "*"), "write", errno.EIO)
    order.files = []
    with pytest.MonkeyPatch.context() as mp:
        order.install(mp.setattr)
        assert main([a.replace("{t}", str(clean)) for a in SWEEP]) == 0
    capfd.readouterr()
    assert len(order.files) >= 6  # two points, study.json, sweep.nc, its figure, report.md
    for n, name in enumerate(order.files, 1):
        where = tmp_path / f"n{n}"
        target = where / Path(name).relative_to(clean)
        with pytest.MonkeyPatch.context() as mp:
            WriteFault(str(target), "write", errno.ENOSPC, log=str(tmp_path / "fault.log")
                       ).install(mp.setattr)  # fmt: skip
            status = main([a.replace("{t}", str(where)) for a in SWEEP])
        assert len(_hits(tmp_path)) == n, f"file {n} ({name}) was not written again"
        check_outcome(status, capfd.readouterr().err, target, {}, where)


def test_a_figure_the_worker_cannot_write_is_a_write_error(tmp_path, inject, tiny_run):
    """The run's figure worker (a child process): a figure it cannot write ends the run
    with the write error (exit 2 in the CLI), not as a crashed stage."""
    from validation import run as harness

    state = {}
    for name in ("lambda1 curve", "lambda1 agreement", "critical gains"):
        record = tiny_run / "run" / "stages" / f"{harness.STAGES.index(name)}-{name}.pkl"
        state[name] = pickle.loads(record.with_name(record.name.replace(" ", "_"))
                                   .read_bytes())["value"]  # fmt: skip
    inject(tmp_path / "fig_lLe.png", "write", errno.ENOSPC)
    worker = harness.spawn_figure_worker(tmp_path)
    drawing = harness.start_paper_figures(tmp_path, state, worker, ["fig_lLe.png"])
    with pytest.raises(WriteError) as info:
        harness.finish_paper_figures(drawing)
    harness.stop_paper_figures(drawing)
    assert info.value.path == str(tmp_path / "fig_lLe.png") and "space" in info.value.reason
    assert len(_hits(tmp_path)) == 1 and not (tmp_path / "fig_lLe.png").exists()
    assert _leftovers(tmp_path) == []


def test_a_clip_that_cannot_be_written(tmp_path, capfd, inject):
    """``render`` runs in a fresh process (offscreen OpenGL): the fault reaches it."""
    writer = WRITERS["render: GIF clip"]
    inject(tmp_path / writer.target, "write", errno.ENOSPC)
    status = main(_argv(writer, tmp_path))
    err = capfd.readouterr().err
    if status == 2 and "no offscreen OpenGL" in err:
        pytest.skip(err.strip().splitlines()[-1])
    assert len(_hits(tmp_path)) == 1, err[-2000:]  # in the child process
    check_outcome(status, err, tmp_path / "c.gif", {}, tmp_path)


def test_a_recording_log_that_cannot_be_written(tmp_path, capfd, inject):
    """The ``.jsonl`` log is append-only by design (a trial is recorded as it runs); a
    write error is one line naming it, and what is on disk still reads as a recording."""
    from validation.experiment.recording import load_jsonl

    inject(tmp_path / "bots" / "*.jsonl", "write", errno.ENOSPC, nth=200)
    status = main(["experiment", "bots", "--out", str(tmp_path / "bots"), "--mode", "single",
                   "--trials", "1", "--trial-duration", "2"])  # fmt: skip
    err = capfd.readouterr().err
    (hit,) = _hits(tmp_path)
    log = Path(hit.split(" ", 2)[2])
    lines = [x for x in err.splitlines() if x.startswith("cip-validate: error")]
    assert status == 2 and len(lines) == 1 and str(log) in lines[0], err[-2000:]
    assert "Traceback" not in err
    assert len(load_jsonl(log).time) > 0  # the samples before the fault, the cut line left out
    assert not log.with_suffix(".npz").exists()


def test_the_engines_figure_and_the_model_files_under_a_fault(tmp_path, inject):
    """Writers reached by a function: the error names the file in one line."""
    from cip.model import write_models
    from validation.engines import speed_accuracy_figure

    results = {"engines": [{"engine": "mujoco", "status": "pass",
                            "throughput": {"realization_steps_per_s": 1e6},
                            "trajectory_distance": {"coupled": 1e-3}}]}  # fmt: skip
    png = tmp_path / "speed.png"
    png.write_bytes(b"old")
    inject(png, "write", errno.EIO)
    with pytest.raises(WriteError) as info:
        speed_accuracy_figure(results, png)
    assert str(png) in info.value.message() and "\n" not in info.value.message()
    assert png.read_bytes() == b"old"
    inject(tmp_path / "models" / "*.xml", "replace", errno.EACCES)
    (tmp_path / "models").mkdir()
    with pytest.raises(WriteError) as info:
        write_models(tmp_path / "models")
    assert "Permission denied" in info.value.message()
    assert list((tmp_path / "models").iterdir()) == [] and _leftovers(tmp_path) == []


def test_the_fault_catches_a_writer_that_writes_in_place(tmp_path):
    """The fixture can fail: a file written in place under its final name is left half
    written by the fault, and :func:`complete` sees it (an atomic writer leaves the old)."""
    target = tmp_path / "a.json"
    target.write_text('{"old": 1}')
    fault = WriteFault(str(target), "write", errno.ENOSPC)
    with pytest.MonkeyPatch.context() as mp:
        fault.install(mp.setattr)
        with pytest.raises(OSError), open(target, "w") as f:  # in place: not atomic
            f.write(json.dumps({"x": list(range(100))}))
    assert fault.seen == 1 and not complete(target) and target.read_text() != '{"old": 1}'
    target.write_text('{"old": 1}')
    with pytest.MonkeyPatch.context() as mp:
        WriteFault(str(target), "write", errno.ENOSPC).install(mp.setattr)
        with pytest.raises(WriteError):
            write_text(target, json.dumps({"x": list(range(100))}))
    assert target.read_text() == '{"old": 1}' and _leftovers(tmp_path) == []


def test_a_crashed_run_whose_results_cannot_be_written(tmp_path, capfd, inject, tiny_run,
                                                       tiny_profile, monkeypatch):  # fmt: skip
    """A stage crashes (the engine broke) and the partial results.json naming it cannot
    be written: the write error is said (exit 2), the last whole results.json stays."""
    from validation import run as harness

    shutil.copytree(tiny_run, tmp_path, dirs_exist_ok=True)
    (tmp_path / _stage_record("lambda1 curve")).unlink()

    def broken(*args, **kwargs):
        raise RuntimeError("the engine broke")

    monkeypatch.setattr(harness.paper, "lyapunov_curve", broken)
    before = _tree(tmp_path)
    # the crash's partial results.json: after one written per stage before the crashed one
    inject(tmp_path / "run" / "results.json", "replace", errno.EIO,
           nth=STAGES.index("lambda1 curve") + 1)  # fmt: skip
    status = main([a.replace("{t}", str(tmp_path)) for a in RUN])
    err = capfd.readouterr().err
    assert len(_hits(tmp_path)) == 1, err[-2000:]
    check_outcome(status, err, tmp_path / "run" / "results.json", before, tmp_path, exact=False)
    assert json.loads((tmp_path / "run" / "results.json").read_text())["partial"] is True


def test_a_baseline_of_its_own_run_under_a_fault(tmp_path, capfd, inject, tiny_run,
                                                 monkeypatch):  # fmt: skip
    """``baseline`` without ``--from`` runs the suite (here: the tiny run's results, read
    back) and writes them with ``write_json``."""
    from validation import run as harness

    results = json.loads((tiny_run / "run" / "results.json").read_text())
    monkeypatch.setattr(harness, "run_validation", lambda *a, **k: results)
    out = tmp_path / "b.json"
    out.write_text('{"old": true}')
    before = _tree(tmp_path)
    inject(out, "write", errno.ENOSPC)
    status = main(["baseline", "--profile", "smoke", "--out", str(out)])
    check_outcome(status, capfd.readouterr().err, out, before, tmp_path)
