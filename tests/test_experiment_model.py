"""The experiment's task model, trial rules, bots, recordings and analysis (no server)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from cipcore.params import ParameterError
from validation.experiment.analysis import analyse_trial, table
from validation.experiment.bot import BotSpec, PseudoNeuralBot
from validation.experiment.headless import run_bot_trial
from validation.experiment.protocol import BadMessage, RateLimiter, parse
from validation.experiment.recording import Recorder, load_trial, make_header
from validation.experiment.screen import UNIT_PER_PX, to_model, to_pixel
from validation.experiment.task import (
    ReducedTask,
    TaskSettings,
    experiment_params,
    make_task,
    semi_implicit_map,
)
from validation.experiment.trial import Trial


def test_screen_maps_range_to_pixels_1_to_1200():
    assert to_pixel(-3.0) == pytest.approx(1.0)
    assert to_pixel(3.0) == pytest.approx(1200.0)
    assert to_model(to_pixel(0.37)) == pytest.approx(0.37)
    assert UNIT_PER_PX == pytest.approx(6 / 1199)


def test_frame_map_equals_twenty_semi_implicit_substeps():
    p = experiment_params()
    m, g = semi_implicit_map(p.alpha, p.gamma, p.dt, 20)
    y, v, base = 0.3, -0.2, -0.1
    for _ in range(20):  # the reduced stepper: velocity first, then position
        v += p.dt * (-p.gamma * v + p.alpha * (y - base))
        y += p.dt * v
    np.testing.assert_allclose(m @ [0.3, -0.2] + g * base, [y, v], rtol=1e-13)


def test_coupled_tip_follows_the_mean_of_the_two_lower_ends():
    """2 q_T'' + 2 gamma q_T' = alpha (Dq_1 + Dq_2) (eq. (5))."""
    s = TaskSettings(mode="coupled")
    a, b = ReducedTask(s), ReducedTask(TaskSettings(mode="single"))
    a.advance(np.array([-0.7, 0.1]))
    b.advance(np.array([-0.3]))
    np.testing.assert_array_equal(np.concatenate(a.tips()), np.repeat(np.concatenate(b.tips()), 2))


def test_initial_screen_is_the_papers():
    """x_T(0) = -0.5, x_M(0) = -0.6; q_T = -0.5, q_M1 = -0.6, q_M2 = 0.6; rod l = 1."""
    single = Trial(TaskSettings(mode="single"), make_task("reduced", TaskSettings()))
    s0 = single.frame([None])
    assert (s0.tip_position, s0.base_position, s0.base_velocity) == ([-0.5], [-0.6], [0.0])
    cs = TaskSettings(mode="coupled")
    coupled = Trial(cs, make_task("reduced", cs))
    c0 = coupled.frame([None, None])
    np.testing.assert_allclose(np.array(c0.tip_position) - c0.base_position, [0.1, -0.1])
    tips, thins = coupled.screen_positions()
    np.testing.assert_allclose(thins, [-0.6, 0.6])
    assert tips[1] - tips[0] == pytest.approx(1.0)


def test_first_pixel_anchors_and_one_unit_is_1199_over_6_pixels():
    s = TaskSettings(mode="single")
    trial = Trial(s, make_task("reduced", s))
    trial.frame([500.0])
    smp = trial.frame([500.0 + 1199 / 6])
    assert smp.base_position[0] == pytest.approx(-0.6 + 1.0)
    assert smp.base_velocity[0] == pytest.approx(1.0 / 0.02)


def test_line_out_of_range_ends_the_trial_and_keeps_the_sample():
    s = TaskSettings(mode="coupled")
    trial = Trial(s, make_task("reduced", s))
    trial.frame([600.0, 600.0])
    smp = trial.frame([600.0, 600.0 + 2.5 / UNIT_PER_PX])  # q_M2 to 3.1 on the screen
    assert trial.end_reason == "out_of_range" and "thin line 2" in trial.end_detail
    assert smp.k == 1 and trial.end_time == pytest.approx(0.02)
    with pytest.raises(RuntimeError):
        trial.frame([600.0, 600.0])


def test_time_ends_the_trial_after_duration():
    s = TaskSettings(mode="single", duration=0.1)
    trial = Trial(s, make_task("reduced", s))
    n = 0
    while not trial.ended:
        trial.frame([None])
        n += 1
    assert trial.end_reason == "time" and n == 6  # t = 0, 0.02, ..., 0.1


def test_bad_settings_name_the_parameter():
    with pytest.raises(ParameterError, match="mode"):
        TaskSettings(mode="triple")
    with pytest.raises(ParameterError, match="engine"):
        make_task("bullet", TaskSettings())
    with pytest.raises(ParameterError, match="trial duration"):
        TaskSettings(duration=-1)
    with pytest.raises(ParameterError, match="tau"):
        PseudoNeuralBot(BotSpec(21, 0.0105, 0.0), experiment_params(), 0.02, -0.6)


@pytest.mark.parametrize(("tau", "beta"), [(0.1, 600.0), (0.14, 400.0), (0.2, 300.0)])
def test_noise_free_bot_delay_is_recovered(tmp_path, tau, beta):
    """Issue 13: a noise-free bot of delay tau gives tau_hat = tau +- 0.02 s.

    In the single model x_M'' + gamma x_M' = beta e(t - tau) and x_T'' + gamma x_T'
    = alpha e, so x_M' = (beta/alpha) x_T'(t - tau): the STCC peaks at tau.  A
    noise-free linear loop keeps moving only near its oscillatory stability
    boundary; each beta puts the rightmost root at Re s = -0.5 .. -0.9 1/s.  (Far
    from it the motion is a damped oscillation e^(-lambda t) cos(omega t), for which
    the paper's STCC, normalised over the unlagged window, peaks early by
    atan(lambda/omega)/omega: 0.04 s at tau = 0.1, beta = 300.)
    """
    out = run_bot_trial(TaskSettings(mode="single", duration=60.0),
                        [BotSpec(beta, tau, 0.0, seed=0)], ["A"], 1, tmp_path)  # fmt: skip
    (res,) = analyse_trial(load_trial(out))
    assert res.end == "time"
    assert abs(res.tau_hat - tau) <= 0.02 + 1e-9


def test_identical_noise_free_bots_coupled_leave_the_tip_still(tmp_path):
    """Symmetric start (Dq = +-0.1) and identical deterministic bots: Dq_1 + Dq_2 = 0
    forever, q_T never moves, and tau_hat is undefined (NaN), not a number from rounding."""
    out = run_bot_trial(TaskSettings(mode="coupled", duration=20.0),
                        [BotSpec(400.0, 0.14, 0.0, 0)] * 2, ["A", "B"], 1, tmp_path)  # fmt: skip
    tr = load_trial(out)
    assert np.abs(tr["tip_velocity"]).max() < 1e-9
    assert all(np.isnan(r.tau_hat) for r in analyse_trial(tr))


def test_same_seed_same_recording_other_seed_differs(tmp_path):
    s = TaskSettings(mode="coupled", duration=4.0)
    runs = [
        load_trial(
            run_bot_trial(
                s, [BotSpec(21, 0.1, 0.6, a), BotSpec(21, 0.1, 0.6, b)], ["A", "B"], 1, tmp_path
            )
        )
        for a, b in ((1, 2), (1, 2), (1, 3))
    ]
    np.testing.assert_array_equal(runs[0]["base_position"], runs[1]["base_position"])
    assert not np.array_equal(runs[0]["base_position"], runs[2]["base_position"])


def test_killed_recording_loads_without_its_torn_last_line(tmp_path):
    s = TaskSettings(mode="single", duration=1.0)
    trial = Trial(s, make_task("reduced", s))
    header = make_header(s.as_dict(), "reduced", ["A"], [{"kind": "human"}], 3, "x", s.substeps)
    rec = Recorder(tmp_path / "t", header)
    for _ in range(10):
        rec.append(trial.frame([100.0]))
    with open(rec.path, "a") as f:
        f.write('{"k": 10, "t": 0.2, "wal')  # a write cut by SIGKILL
    tr = load_trial(tmp_path / "t.jsonl")
    assert tr.attrs["end"] == {"reason": "unfinalised"} and tr.time.size == 10
    assert tr.sample_interval == pytest.approx(0.02) and tr.attrs["trial_index"] == 3


def test_finalised_npz_is_in_the_suite_schema(tmp_path):
    out = run_bot_trial(TaskSettings(mode="coupled", duration=1.0),
                        [BotSpec(21, 0.1, 0.6, 1), BotSpec(21, 0.1, 0.6, 2)], ["A", "B"],
                        2, tmp_path)  # fmt: skip
    tr = load_trial(out)
    assert out.suffix == ".npz" and tr["balancing_error"].shape == (1, 51, 2)
    np.testing.assert_array_equal(tr["tip_position"][0, :, 0], tr["tip_position"][0, :, 1])
    a = tr.attrs
    assert a["end"]["reason"] == "time" and a["pair"] == ["A", "B"] and a["mode"] == "coupled"
    assert a["settings"]["params"]["alpha"] == 21.0 and a["seats"][1]["seed"] == 2
    assert "numpy" in a["versions"] and a["start_time"].endswith("Z")
    rows = table(analyse_trial(tr), "rms")
    assert set(rows) == {("coupled", "A"), ("coupled", "B")}


@pytest.mark.parametrize(
    "text",
    [
        "not json",
        "[1, 2]",
        '{"type": "fly"}',
        '{"type": "mouse", "x": NaN}',
        '{"type": "mouse", "x": true}',
        '{"type": "mouse", "x": 1e9}',
        '{"type": "mouse"}',
        '{"type": "join", "code": "short", "label": "A"}',
        '{"type": "join", "code": "abcdefghijkl", "label": "<script>"}',
        '{"type": "create", "token": "t", "mode": "single", "trial": 0, '
        '"seats": [{"kind": "human", "label": "A"}]}',
        '{"type": "create", "token": "t", "mode": "coupled", "trial": 1, '
        '"seats": [{"kind": "human", "label": "A"}]}',
        '{"type": "create", "token": "t", "mode": "single", "trial": 1, "seats": '
        '[{"kind": "bot", "label": "A", "beta": 21, "tau": 5, "nu": 0.6, "seed": 1}]}',
        json.dumps({"type": "mouse", "x": 1.0, "pad": "x" * 3000}),
    ],
)
def test_bad_messages_are_rejected(text):
    with pytest.raises(BadMessage):
        parse(text)


def test_good_messages_and_rate_limit():
    assert parse('{"type": "mouse", "x": 600.5}') == {"type": "mouse", "x": 600.5, "t": None}
    m = parse(json.dumps({"type": "create", "token": "t", "mode": "coupled", "trial": 4, "seats": [
        {"kind": "human", "label": "A"},
        {"kind": "bot", "label": "B", "beta": 21, "tau": 0.1, "nu": 0.6, "seed": 7}]}))  # fmt: skip
    assert m["seats"][1]["seed"] == 7 and m["trial"] == 4
    lim = RateLimiter(rate=100.0, burst=5.0)
    assert sum(lim.allow(0.0) for _ in range(20)) == 5
    assert lim.allow(0.011)  # one token back after 10 ms


def test_mujoco_engine_follows_the_reduced_one_at_first(tmp_path):
    """The rigid body (cart servoed to the mouse, bob on a massless pole) and the reduced
    tip agree while the motion is small: over the first second within 5e-3 units."""
    pytest.importorskip("mujoco")
    s = TaskSettings(mode="coupled", duration=1.0)
    bots = [BotSpec(21, 0.1, 0.6, 1), BotSpec(21, 0.1, 0.6, 2)]
    red, full = (
        load_trial(run_bot_trial(s, bots, ["A", "B"], 1, tmp_path, engine=e))
        for e in ("reduced", "mujoco")
    )
    assert full.attrs["engine"] == "mujoco" and full.attrs["end"]["reason"] == "time"
    diff = np.abs(full["tip_position"] - red["tip_position"]).max()
    assert diff < 5e-3
    # the rod keeps the two tips' displacements together: to 1e-4 (a soft constraint on the
    # 3-D distance; the bobs' heights L cos(theta_i) differ a little)
    tips = full["tip_position"][0]
    assert 0 < np.abs(tips[:, 0] - tips[:, 1]).max() < 1e-4
    assert not np.array_equal(full["tip_position"], red["tip_position"])


def _recorder(tmp_path):
    from validation.experiment import recording

    s = TaskSettings(mode="single", duration=1.0)
    header = make_header(s.as_dict(), "reduced", ["A"], [{"kind": "human"}], 1, "x", s.substeps)
    return recording, Trial(s, make_task("reduced", s)), Recorder(tmp_path / "t", header)


def test_a_slow_fsync_never_holds_the_frame_loop(tmp_path, monkeypatch):
    """The once-a-second fsync runs on a thread of its own: a disk that takes 0.5 s per
    fsync leaves every append (one 20 ms frame's write) fast; the end is still fsynced."""
    import threading
    import time

    recording, trial, rec = _recorder(tmp_path)
    real, synced = recording.os.fsync, []

    def slow_fsync(fd):
        time.sleep(0.5)
        synced.append(threading.current_thread().name)
        real(fd)

    monkeypatch.setattr(recording.os, "fsync", slow_fsync)
    monkeypatch.setattr(recording, "FSYNC_INTERVAL", 0.0)  # an fsync due at every frame
    worst = 0.0
    for _ in range(20):
        t = time.perf_counter()
        rec.append(trial.frame([100.0]))
        worst = max(worst, time.perf_counter() - t)
    assert worst < 0.1, f"an append waited {worst:.3f} s for the disk"
    path = rec.finalize({"reason": "time"})
    assert synced and synced[0].startswith("recording-fsync")  # off the loop's thread
    assert synced[-1] == threading.current_thread().name  # the end record: fsynced here
    assert load_trial(path).time.size == 20


def test_an_fsync_error_on_the_thread_is_raised_by_the_next_sample(tmp_path, monkeypatch):
    import errno
    import time

    recording, trial, rec = _recorder(tmp_path)

    def full(fd):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(recording.os, "fsync", full)
    monkeypatch.setattr(recording, "FSYNC_INTERVAL", 0.0)
    rec.append(trial.frame([100.0]))  # starts the failing fsync
    time.sleep(0.2)
    with pytest.raises(OSError, match="No space left"):
        rec.append(trial.frame([100.0]))
