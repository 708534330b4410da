"""A sweep's worker count follows its work: cheap points run in this process."""

from __future__ import annotations

from validation.sweep import Study, SweepPool, run_sweep
from validation.sweeps.schedule import WORKER_STARTUP_S, choose_workers


def test_choose_workers_weighs_the_time_saved_against_a_start_up():
    assert choose_workers(2, 0.1, 3)[0] == 1  # 0.15 s saved: not worth a process
    assert choose_workers(2, 10.0, 3)[0] == 2  # 15 s saved
    assert choose_workers(8, 10.0, 3)[0] == 3  # at most one per point
    assert choose_workers(1, 100.0, 10)[0] == 1  # one core
    w, why = choose_workers(2, 2 * WORKER_STARTUP_S / 1.0, 1)
    assert w == 1 and why.startswith("in this process")


def test_default_sweep_of_cheap_points_runs_here_and_says_so(tmp_path):
    study = Study(name="t", model="single", engine="reduced", metrics=("rms",),
                  realizations=2, duration=0.5, seed=3, fixed={"beta": 21.0},
                  grid={"amplitude": [0.001, 0.002, 0.003]})  # fmt: skip
    rep = run_sweep(study, tmp_path / "s")
    assert rep.computed == 3
    assert rep.schedule.startswith("in this process"), rep.schedule
    asked = run_sweep(study, tmp_path / "t", pool=SweepPool(workers=1))
    assert asked.schedule == "1 worker process(es), as asked"
