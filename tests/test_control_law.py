"""The control law, delay ring and recording rule written once (:mod:`cipcore.control_law`).

The numba kernels inline :mod:`cipcore.control_kernel`; the warp kernels use
:mod:`cipcore.control_warp`, checked here bit-equal to the same law on warp's
CPU device in float64 (``reduced-gpu``) and float32 (``mujoco-warp``); the same ring
and recording functions, compiled by warp, are checked through ``reduced-gpu``'s
trajectories, bit-equal to the numba kernel's.
"""

# no ``from __future__ import annotations``: warp reads the test kernel's annotations as objects
from typing import Any

import numpy as np
import pytest

from cipcore.control_kernel import (
    delayed_random_gain as compiled_law,
)
from cipcore.control_kernel import (
    first_sample,
    ring_exchange,
    ring_next,
    sample_slot,
)
from cipcore.control_law import delayed_random_gain


def _inputs(dtype: type, n: int = 4096, seed: int = 0) -> list[np.ndarray]:
    """Gains (1/s^2 or N/m), noise scales, draws and delayed errors (m) over wide ranges."""
    rng = np.random.default_rng(seed)
    arrays = [rng.uniform(0.1, 400.0, n), rng.uniform(0.0, 30.0, n), rng.standard_normal(n),
              rng.standard_normal(n) * 10.0 ** rng.uniform(-9, 0, n)]  # fmt: skip
    return [a.astype(dtype) for a in arrays]


def test_the_law_is_gain_times_random_gain_times_delayed_error() -> None:
    assert delayed_random_gain(20.0, 0.5, 2.0, 1e-3) == 20.0 * 2.0 * 1e-3
    assert delayed_random_gain(20.0, 0.0, 7.0, -3.0) == -60.0


def test_the_compiled_law_equals_the_numpy_law_bit_for_bit() -> None:
    g, s, xi, e = _inputs(np.float64)
    host = delayed_random_gain(g, s, xi, e)
    compiled = np.array([compiled_law(*args) for args in zip(g, s, xi, e, strict=True)])
    assert np.array_equal(host, compiled)


def test_the_ring_returns_the_value_stored_d_steps_earlier() -> None:
    d, initial = 5, -1.0
    ring = np.full(d, initial)
    p, got = 3, []  # a ring may start at any slot (the slot of step n is n mod d)
    for n in range(23):
        got.append(ring_exchange(ring, p, float(n)))
        p = ring_next(p, d)
    assert got == [initial] * d + [float(n - d) for n in range(d, 23)]


@pytest.mark.parametrize("every", [1, 3, 7])
def test_samples_split_across_calls_equal_one_call(every: int) -> None:
    """Sample rows of calls starting at n0 = 0, 10, 17 hold the steps one call of 30 records."""

    def recorded(n0: int, n: int) -> list[int]:
        start = first_sample(n0, every)
        nrec = -(-(n0 + n) // every) - start
        rows = [(sample_slot(n0 + k, every, start, nrec), n0 + k) for k in range(n)]
        slots = [j for j, _ in rows if j >= 0]
        assert slots == list(range(nrec))
        return [step for j, step in rows if j >= 0]

    whole = recorded(0, 30)
    assert whole == list(range(0, 30, every))
    assert recorded(0, 10) + recorded(10, 7) + recorded(17, 13) == whole


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_the_warp_law_equals_the_shared_law_bit_for_bit(dtype: type) -> None:
    wp = pytest.importorskip(
        "warp", reason="warp-lang is not installed (pip install 'cipval[warp]')"
    )
    from cipcore.control_warp import delayed_random_gain as warp_law

    wp.config.quiet = True

    @wp.kernel
    def apply(g: wp.array(dtype=Any), s: wp.array(dtype=Any), xi: wp.array(dtype=Any),
              e: wp.array(dtype=Any), u: wp.array(dtype=Any)):  # fmt: skip
        i = wp.tid()
        u[i] = warp_law(g[i], s[i], xi[i], e[i])

    args = _inputs(dtype)
    dev = [wp.array(a, device="cpu") for a in args]
    u = wp.zeros(len(args[0]), dtype=wp.dtype_from_numpy(np.dtype(dtype)), device="cpu")
    wp.launch(apply, dim=len(args[0]), inputs=[*dev, u], device="cpu")
    host = delayed_random_gain(*args)  # numpy keeps float32 in float32
    assert host.dtype == dtype
    assert np.array_equal(u.numpy(), host)


@pytest.mark.parametrize("model", ["single", "coupled"])
def test_the_warp_ring_and_recording_equal_the_numba_kernel_bit_for_bit(model, monkeypatch):
    """reduced-gpu on warp's CPU device: its copy of the delay ring and the recording rule
    gives the numba kernel's trajectories exactly (chunks of 300 steps, decimation 7)."""
    pytest.importorskip("warp", reason="warp-lang is not installed (pip install 'cipval[warp]')")
    from cipcore.params import BalanceParams
    from cipcore.scenario import Recording, Scenario
    from reduced import gpu
    from reduced.simulate import simulate

    monkeypatch.setattr(gpu, "GPU_CHUNK_STEPS", 300)
    scn = Scenario(model, BalanceParams(beta=20.306), 1.25, 3, 3, amplitude=1e-3)
    ref = simulate(scn, recording=Recording(decimate=7))
    dev = gpu.simulate_gpu(scn, device="cpu", recording=Recording(decimate=7))
    for field, x in ref.data.items():
        assert np.array_equal(dev[field], x), field


def test_delayed_control_is_the_law_of_the_ring_exchange() -> None:
    """One balancer's delayed control: the ring's old value through the law, the new one in."""
    from cipcore.control_kernel import delayed_control

    ring = np.array([1.5, -2.0, 3.0])
    assert delayed_control(ring, 1, 0.25, 20.0, 0.5, 2.0) == delayed_random_gain(
        20.0, 0.5, 2.0, -2.0
    )
    assert ring[1] == 0.25


def test_euler_step_semi_implicit_uses_the_new_velocity() -> None:
    """The shared stepper: semi-implicit (MuJoCo's Euler) and explicit Euler-Maruyama."""
    from reduced._steps import euler_step

    assert euler_step(1.0, 2.0, 3.0, 0.5, True) == (1.0 + 0.5 * (2.0 + 0.5 * 3.0), 2.0 + 0.5 * 3.0)
    assert euler_step(1.0, 2.0, 3.0, 0.5, False) == (1.0 + 0.5 * 2.0, 2.0 + 0.5 * 3.0)
