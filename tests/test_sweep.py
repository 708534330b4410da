"""Parameter sweeps: datasets, seeds, resume after a kill, Dask."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time

import numpy as np
import pytest
import xarray as xr

from reduced import ParameterError
from validation.sweep import Study, SweepPool, evaluate_point, point_seed, run_sweep


def small_study(**kw) -> Study:
    d = {
        "name": "t", "model": "coupled", "engine": "mujoco",
        "metrics": ("rms", "agreement", "max_angle"), "realizations": 2, "duration": 2.0,
        "seed": 3, "fixed": {"beta": 21.0},
        "grid": {"rod_length_ratio": [0.5, 2.0], "amplitude": [0.001, 0.1]},
    }  # fmt: skip
    d.update(kw)
    return Study(**d)


def open_ds(path):
    with xr.open_dataset(path, engine="scipy") as ds:
        return ds.load()


def test_dataset_has_a_dimension_per_parameter_and_attributes(tmp_path):
    study = small_study(common_random_numbers=True)
    rep = run_sweep(study, tmp_path / "a", pool=SweepPool(workers=1))
    ds = open_ds(rep.dataset_path)
    assert ds["rms"].dims == ("rod_length_ratio", "amplitude", "realization")
    assert ds.sizes == {"rod_length_ratio": 2, "amplitude": 2, "realization": 2}
    assert json.loads(ds.attrs["study"])["name"] == "t"
    assert "mujoco" in json.loads(ds.attrs["versions"])
    # in the linear regime the rod length does not matter (reduced model: l drops out)
    small = ds["agreement"].sel(amplitude=0.001)
    np.testing.assert_allclose(small.sel(rod_length_ratio=0.5), small.sel(rod_length_ratio=2.0),
                               rtol=1e-6)  # fmt: skip
    assert float(small.max()) < 0.01


def test_a_seed_beyond_int32_is_stored(tmp_path):
    """The long fuzz run: a seed of 2663081240 (> 2^31 - 1) ended the sweep in xarray's
    int32 cast of the NetCDF3 attribute; the seed is stored as text, in full."""
    seed = 2**63 - 1
    study = small_study(engine="reduced", metrics=("rms",), grid={"beta": [20.0]},
                        duration=0.05, seed=seed)  # fmt: skip
    ds = open_ds(run_sweep(study, tmp_path / "s", pool=SweepPool(workers=1)).dataset_path)
    assert int(ds.attrs["seed"]) == seed and json.loads(ds.attrs["study"])["seed"] == seed


def test_seeds_per_point_do_not_depend_on_order_or_workers(tmp_path):
    study = small_study()
    seeds = {point_seed(study, p) for p in study.points()}
    assert len(seeds) == 4
    crn = small_study(common_random_numbers=True)
    assert {point_seed(crn, p) for p in crn.points()} == {3}
    a = open_ds(run_sweep(study, tmp_path / "one", pool=SweepPool(workers=1)).dataset_path)
    b = open_ds(run_sweep(study, tmp_path / "two", pool=SweepPool(workers=2)).dataset_path)
    xr.testing.assert_identical(a, b)


@pytest.mark.parametrize("duration", [5.0, pytest.param(20.0, marks=pytest.mark.slow)])
def test_killed_sweep_resumes_without_recomputing(tmp_path, duration):
    """SIGKILL a sweep once some points are on disk; the rerun computes only the rest
    and gives the same dataset as an uninterrupted run (5 s points by default, 20 s slow)."""
    study_file = tmp_path / "s.toml"
    study_file.write_text(f"""
[study]
name = "kill"
model = "coupled"
engine = "mujoco"
metrics = ["rms", "max_angle"]
realizations = 2
duration = {duration}
seed = 5
[grid]
beta = [20.0, 20.5, 21.0, 21.5, 22.0, 22.5, 23.0, 23.5, 24.0, 24.5, 25.0, 25.5]
""")
    out = tmp_path / "run"
    cmd = [sys.executable, "-m", "validation.cli.main", "sweep", str(study_file), "--out", str(out),
           "--workers", "1"]  # fmt: skip
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            start_new_session=True)  # fmt: skip
    deadline = time.time() + 120
    while time.time() < deadline:
        done = list((out / "points").glob("*.json")) if (out / "points").exists() else []
        if len(done) >= 2 or proc.poll() is not None:
            break
        time.sleep(0.05)
    os.killpg(proc.pid, signal.SIGKILL)
    proc.wait()
    before = len(list((out / "points").glob("*.json")))
    assert 1 <= before < 12, "the sweep must be killed halfway"
    res = subprocess.run(cmd, capture_output=True, text=True, check=True)
    assert f"{12 - before} points computed, {before} reused" in res.stdout
    clean = run_sweep(Study.from_toml(study_file), tmp_path / "clean", pool=SweepPool(workers=1))
    xr.testing.assert_identical(open_ds(out / "sweep.nc"), open_ds(clean.dataset_path))


def _interrupted_sweep(out, betas, workers, after):
    """Run a reduced sweep over ``betas`` on ``workers`` that a KeyboardInterrupt stops
    after ``after`` finished points; the points seen before it stopped."""
    study = small_study(engine="reduced", metrics=("rms",), grid={"beta": betas})
    seen = []

    def stop(point):
        seen.append(point)
        if len(seen) == after:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        run_sweep(study, out, pool=SweepPool(workers=workers), on_point=stop)
    return study, seen


def test_interrupted_in_process_keeps_finished_points(tmp_path):
    study, _ = _interrupted_sweep(tmp_path / "r", [20.0, 21.0, 22.0], workers=1, after=2)
    rep = run_sweep(study, tmp_path / "r", pool=SweepPool(workers=1))
    assert (rep.computed, rep.reused) == (1, 2)


def test_interrupted_pool_keeps_the_points_in_progress(tmp_path):
    """Interrupted after the first point of a pool of 2: the points the pool had started
    (it waits for them in any case) are kept as well, not only the first."""
    betas = [20.0 + k for k in range(8)]
    study, seen = _interrupted_sweep(tmp_path / "r", betas, workers=2, after=1)
    kept = len(list((tmp_path / "r" / "points").glob("*.json")))
    assert 2 <= kept <= 8 and kept == len(seen)  # the first one alone before
    rep = run_sweep(study, tmp_path / "r", pool=SweepPool(workers=1))
    assert (rep.computed, rep.reused) == (8 - kept, kept)


@pytest.mark.parametrize("processes", [False, pytest.param(True, marks=pytest.mark.slow)])
def test_dask_local_cluster_gives_the_same_dataset(tmp_path, processes):
    """A Dask cluster of threads (default) or of worker processes (slow) gives the dataset
    of local workers."""
    distributed = pytest.importorskip("dask.distributed")
    study = small_study(engine="reduced", metrics=("rms",), grid={"beta": [20.0, 21.0, 22.0]})
    local = open_ds(run_sweep(study, tmp_path / "local", pool=SweepPool(workers=2)).dataset_path)
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=processes,
                                  dashboard_address=None) as cluster:  # fmt: skip
        rep = run_sweep(
            study, tmp_path / "dask", pool=SweepPool(scheduler=cluster.scheduler_address)
        )
    xr.testing.assert_identical(local, open_ds(rep.dataset_path))


def test_study_validation_names_the_problem(tmp_path):
    with pytest.raises(ParameterError, match="unknown setting 'rod'"):
        small_study(grid={"rod": [1.0]})
    with pytest.raises(ParameterError, match="beta"):
        small_study(grid={"beta": [20.0, -1.0]})
    with pytest.raises(ParameterError, match="metrics"):
        small_study(metrics=("lambda2",))
    with pytest.raises(ParameterError, match="integrator"):
        small_study(grid={"integrator": ["Euler", "Leapfrog"]})
    run_sweep(small_study(grid={"beta": [20.0]}, engine="reduced", metrics=("rms",)),
              tmp_path / "x")  # fmt: skip
    with pytest.raises(ParameterError, match="another study"):
        run_sweep(small_study(grid={"beta": [21.0]}, engine="reduced", metrics=("rms",)),
                  tmp_path / "x")  # fmt: skip


def test_evaluate_point_is_pure():
    study = small_study(engine="reduced", metrics=("rms", "lambda1"),
                        grid={"beta": [20.0, 21.0], "amplitude": [0.001, 0.1]})  # fmt: skip
    p = study.points()[0]
    assert evaluate_point(study.as_dict(), p) == evaluate_point(study.as_dict(), p)


def test_string_parameters_and_report(tmp_path):
    from validation.sweep import write_sweep_report

    study = small_study(grid={"integrator": ["Euler", "RK4"]}, metrics=("agreement",))
    run_sweep(study, tmp_path / "s", pool=SweepPool(workers=1))
    report = write_sweep_report(study, tmp_path / "s").read_text()
    assert "| RK4 |" in report and (tmp_path / "s" / "sweep_agreement.png").exists()


RACE_STUDY = """
[study]
name = "{name}"
model = "coupled"
engine = "reduced"
metrics = ["rms", "lambda1"]
realizations = 8
duration = {duration}
seed = 11
[grid]
beta = [20.0, 21.0, 22.0, 23.0]
"""


@pytest.mark.parametrize(
    "durations", [(5.0, 7.5), pytest.param((20.0, 30.0), marks=pytest.mark.slow)]
)
def test_two_studies_raced_into_one_directory_never_mix(tmp_path, durations):
    """Two studies differing only in duration, started together into one --out: one
    wins, the other fails with one line (directory in use, naming the holder, or holding
    another study), and the winner's dataset equals a clean run of its own study."""
    files = {}
    for name, duration in zip(("short", "long"), durations, strict=True):
        files[name] = tmp_path / f"{name}.toml"
        files[name].write_text(RACE_STUDY.format(name=name, duration=duration))
    out = tmp_path / "shared"
    procs = {
        name: subprocess.Popen(
            [sys.executable, "-m", "validation.cli.main", "sweep", str(f), "--out", str(out),
             "--workers", "1"],
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        )
        for name, f in files.items()
    }  # fmt: skip
    results = {name: (p.wait(timeout=300), *p.communicate()) for name, p in procs.items()}
    winners = [n for n, (code, _, _) in results.items() if code == 0]
    assert len(winners) >= 1, results
    for _name, (code, _, err) in results.items():
        if code != 0:
            assert code == 2, err
            lines = [ln for ln in err.splitlines() if ln.startswith("cip-validate: error:")]
            assert len(lines) == 1 and "Traceback" not in err, err
            assert "in use by another sweep (pid" in lines[0] or "holds another study" in lines[0]
    # a loser that found the directory free after the winner finished is refused too, so
    # exactly one study's files are in the directory
    assert len(winners) == 1, results
    win = Study.from_toml(files[winners[0]])
    names = {p.name.split("-")[0] for p in (out / "points").glob("*.json")}
    assert names == {win.fingerprint()}
    assert json.loads((out / "study.json").read_text())["name"] == winners[0]
    clean = run_sweep(win, tmp_path / "clean", pool=SweepPool(workers=1))
    xr.testing.assert_identical(open_ds(out / "sweep.nc"), open_ds(clean.dataset_path))
    assert not list(out.glob("*.tmp*")) and not list((out / "points").glob("*.tmp*"))


def test_locked_directory_fails_at_once_naming_the_holder(tmp_path):
    from validation.sweeps import DirectoryLock

    study = small_study(engine="reduced", metrics=("rms",), grid={"beta": [20.0, 21.0]})
    where = tmp_path / "locked"
    where.mkdir()
    with DirectoryLock(where):
        t = time.perf_counter()
        with pytest.raises(
            ParameterError, match=f"in use by another sweep \\(pid {os.getpid()} on"
        ):
            run_sweep(study, where, pool=SweepPool(workers=1))
        assert time.perf_counter() - t < 5
    rep = run_sweep(study, where, pool=SweepPool(workers=1))  # released: the same study runs
    assert rep.computed == 2
    rep = run_sweep(
        study, where, pool=SweepPool(workers=1)
    )  # the same study again: reuses every point
    assert (rep.computed, rep.reused) == (0, 2)


def test_point_files_are_keyed_by_the_study_not_only_the_point(tmp_path):
    a = small_study(engine="reduced", metrics=("rms",), grid={"beta": [20.0]})
    b = small_study(engine="reduced", metrics=("rms",), grid={"beta": [20.0]}, duration=3.0)
    from validation.sweeps import Store

    assert (
        Store(tmp_path / "a", a).path({"beta": 20.0}).name
        != Store(tmp_path / "b", b).path({"beta": 20.0}).name
    )
    run_sweep(a, tmp_path / "c", pool=SweepPool(workers=1))
    with pytest.raises(ParameterError, match="holds another study"):
        run_sweep(b, tmp_path / "c", pool=SweepPool(workers=1))


def test_divergence_is_recorded_per_point(tmp_path):
    """beta = 2 is far below the stability threshold: the reduced model's balancing
    error leaves |e| < L within seconds; the point records when, beta = 21 does not."""
    study = small_study(engine="reduced", metrics=("rms",), grid={"beta": [2.0, 21.0]},
                        duration=20.0, fixed={})  # fmt: skip
    rep = run_sweep(study, tmp_path / "div", pool=SweepPool(workers=1))
    ds = open_ds(rep.dataset_path)
    assert list(ds["diverged"].values) == [1, 0]
    t = ds["divergence_time"].sel(beta=2.0).values
    assert np.all((t > 0) & (t < 20.0))
    assert np.all(np.isnan(ds["divergence_time"].sel(beta=21.0).values))
    assert [d["point"] for d in rep.diverged] == [{"beta": 2.0}]
