"""MuJoCo's profiling timers off inside cipval's rollouts (cip.mjtimer)."""

from __future__ import annotations

import sys
import threading

import mujoco
import numpy as np
import pytest
from mujoco import rollout

from cip import mjtimer
from cip.model import CIPParams, build

SPEC = mujoco.mjtState.mjSTATE_FULLPHYSICS


def _roll(m: mujoco.MjModel, d: mujoco.MjData) -> np.ndarray:
    d.qpos[:] = 1e-3
    mujoco.mj_forward(m, d)
    s0 = np.empty(mujoco.mj_stateSize(m, SPEC))
    mujoco.mj_getState(m, d, s0, SPEC)
    ctrl = np.random.default_rng(3).normal(0.0, 1e-2, (3, 200, m.nu))
    state, _ = rollout.rollout(m, d, np.tile(s0, (3, 1)), ctrl)
    return state


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="the lookup is checked on Linux")
def test_the_timer_symbol_is_found():
    """A lookup that silently found nothing would leave the timers on everywhere."""
    assert mjtimer.AVAILABLE
    assert mjtimer.timers_on()  # the bindings install their clock at import


@pytest.mark.skipif(not mjtimer.AVAILABLE, reason="mjcb_time not found in the MuJoCo library")
@pytest.mark.parametrize("model", ["single", "coupled"])
def test_states_are_bit_identical_and_timers_stay_still(model):
    m = build(model, CIPParams())
    d_on, d_off = mujoco.MjData(m), mujoco.MjData(m)
    on = _roll(m, d_on)
    with mjtimer.timers_off():
        assert not mjtimer.timers_on()
        off = _roll(m, d_off)
    assert mjtimer.timers_on()
    np.testing.assert_array_equal(on, off)
    assert d_on.timer[mujoco.mjtTimer.mjTIMER_STEP].duration > 0
    assert d_off.timer[mujoco.mjtTimer.mjTIMER_STEP].duration == 0
    assert d_off.timer[mujoco.mjtTimer.mjTIMER_STEP].number > 0  # the steps ran


@pytest.mark.skipif(not mjtimer.AVAILABLE, reason="mjcb_time not found in the MuJoCo library")
def test_overlapping_threads_restore_the_callback_once_all_have_left():
    """Thread B enters while A is inside; A leaves first: the timers stay off until B
    leaves, then the bindings' clock is back (not the NULL that B saw on entry)."""
    a_in, b_in, a_out = threading.Event(), threading.Event(), threading.Event()
    seen = {}

    def a() -> None:
        with mjtimer.timers_off():
            a_in.set()
            b_in.wait(5)
        a_out.set()

    def b() -> None:
        a_in.wait(5)
        with mjtimer.timers_off():
            b_in.set()
            a_out.wait(5)
            seen["after A left"] = mjtimer.timers_on()

    threads = [threading.Thread(target=a), threading.Thread(target=b)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(10)
    assert seen == {"after A left": False}
    assert mjtimer.timers_on()


def test_an_exception_inside_restores_the_timers():
    on = mjtimer.timers_on()
    with pytest.raises(RuntimeError), mjtimer.timers_off():
        raise RuntimeError("inside")
    assert mjtimer.timers_on() == on
