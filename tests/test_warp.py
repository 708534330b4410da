"""The warp engines (mujoco-warp, reduced-gpu) on warp's CPU device, and their GPU-only paths.

Skipped, with the reason, where ``warp-lang``/``mujoco-warp`` are absent; the
CUDA-only checks skip without a CUDA device.  First use compiles MuJoCo Warp's
kernels for the CPU (about a minute, cached).  Marked ``warp``: left out of the
default run, run by CI (which installs the ``[warp]`` extra) as a step of its own,
``CIPVAL_WARP_DEVICE=cpu pytest -m warp``, with the warp engines' contract tests.
"""

from __future__ import annotations

import numpy as np
import pytest

from cip.runner import RigidBody
from cipcore.gpu import DEVICE_ENV, warp_unavailable
from cipcore.models import get_model
from cipcore.noise import GainNoise
from cipcore.params import BalanceParams
from cipcore.scenario import Execution, Recording, Scenario

pytestmark = pytest.mark.warp


@pytest.fixture(autouse=True)
def _needs_warp() -> None:
    """Skip without warp-lang or mujoco-warp; imported when a test runs, not at collection
    (the default run deselects this module and should not pay the imports, about 2 s)."""
    pytest.importorskip("warp", reason="warp-lang is not installed (pip install 'cipval[warp]')")
    pytest.importorskip(
        "mujoco_warp", reason="mujoco-warp is not installed (pip install 'cipval[warp]')"
    )


P = BalanceParams(beta=20.306)


def _rel(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.linalg.norm(a - b) / np.linalg.norm(b))


def _cuda() -> bool:
    try:
        import warp as wp
    except ImportError:  # the skipif below runs before the fixture that skips without warp
        return False

    wp.config.quiet = True
    return wp.is_cuda_available()


# ------------------------------------------------------------ reduced-gpu
@pytest.mark.parametrize("model", ["single", "coupled"])
@pytest.mark.parametrize("stepper", ["semi-implicit", "explicit"])
def test_reduced_gpu_kernel_equals_the_cpu_kernel(model, stepper, monkeypatch) -> None:
    """Same draws, same map: the warp kernel on the CPU device reproduces the numba kernel
    across chunk boundaries (chunks of 300 steps, a partial last one, decimation 7)."""
    from reduced import gpu
    from reduced.simulate import simulate

    monkeypatch.setattr(gpu, "GPU_CHUNK_STEPS", 300)
    scn = Scenario(model, P, 1.25, 3, 3, amplitude=1e-3)
    kw = {"stepper": stepper, "recording": Recording(decimate=7)}
    ref = simulate(scn, **kw)
    tr = gpu.simulate_gpu(scn, device="cpu", **kw)
    assert tr.attrs["engine"] == "reduced-gpu"
    for f, x in ref.data.items():
        assert tr[f].shape == x.shape
        assert np.abs(tr[f] - x).max() <= 1e-12 * np.abs(x).max(), f


def test_reduced_gpu_same_draws_for_any_batch_split() -> None:
    from reduced.gpu import simulate_gpu

    whole = simulate_gpu(Scenario("coupled", P, 0.5, 4, 11, amplitude=1e-3), device="cpu")
    part = simulate_gpu(
        Scenario("coupled", P, 0.5, amplitude=1e-3),
        noise=GainNoise(11, 2, 2, first_realization=2),
        device="cpu",
    )
    assert np.array_equal(whole["balancing_error"][2:], part["balancing_error"])


# ------------------------------------------------------------ availability
def test_without_cuda_the_engines_say_why(monkeypatch) -> None:
    if _cuda():
        pytest.skip("a CUDA device is present")
    monkeypatch.delenv(DEVICE_ENV, raising=False)
    reason = warp_unavailable(("warp",))
    assert reason is not None and "no CUDA device" in reason and DEVICE_ENV in reason
    monkeypatch.setenv(DEVICE_ENV, "cpu")
    assert warp_unavailable(("warp",)) is None


def test_a_bad_device_choice_is_one_line_naming_the_variable(monkeypatch) -> None:
    monkeypatch.setenv(DEVICE_ENV, "tpu")
    reason = warp_unavailable(("warp",))
    assert reason is not None and DEVICE_ENV in reason and "tpu" in reason
    assert "\n" not in reason


# ------------------------------------------------------------ mujoco-warp


def _cpu_backend():
    from cip.engines.warp_batch import WarpRollout

    return type("WarpRollout", (WarpRollout,), {"device": "cpu"})


def test_mujoco_warp_reproduces_mujoco_cpu_within_float32() -> None:
    """Same controls' law, same draws: float32 MuJoCo Warp stays within float32 rounding
    (grown over 500 steps of delayed feedback) of float64 MuJoCo on the CPU."""
    from cip.simulate import simulate_full

    ref = simulate_full(Scenario("single", P, 0.5, 2, 7, amplitude=1e-3))
    tr = simulate_full(
        Scenario("single", P, 0.5, 2, 7, amplitude=1e-3),
        body=RigidBody(backend=_cpu_backend(), name="mujoco-warp"),
    )
    for f in ("balancing_error", "base_position", "angle"):
        assert _rel(tr[f], ref[f]) < 1e-5, f
    assert tr.attrs["diverged"] is None


def test_mujoco_warp_gives_the_same_numbers_on_one_thread_and_on_two() -> None:
    """The shared driver steps realisation blocks on threads; warp's kernel building is
    serialised (two threads parsing kernels at once failed on CPython < 3.11.8)."""
    from cip.simulate import simulate_full

    scn, body = Scenario("coupled", P, 0.2, 2, 4, amplitude=1e-3), RigidBody(backend=_cpu_backend())
    one = simulate_full(scn, body=body, execution=Execution(threads=1))
    two = simulate_full(scn, body=body, execution=Execution(threads=2))
    assert np.array_equal(one["balancing_error"], two["balancing_error"])


def _device_control_errors(model: str, n_steps: int, amplitude: float, seed: int):
    from cip.engines.warp import WarpChunks
    from cip.model import CIPParams

    nc = get_model(model).n_controllers
    chunks = WarpChunks(get_model(model), P, 2, amplitude, CIPParams.from_reduced(P), device="cpu")
    xi = GainNoise(seed, 2, nc).next_chunk(n_steps)
    d = chunks.max_chunk
    out = [chunks.advance(xi[:, k : k + d]) for k in range(0, n_steps, d)]
    return np.concatenate([o["balancing_error"] for o in out], axis=1)


@pytest.mark.parametrize("model", ["single", "coupled"])
def test_control_on_the_device_equals_the_host_control(model) -> None:
    """The ring-buffer control kernel applies the same law, delay and draws as CIPRunner."""
    from cip.simulate import simulate_full

    n = 400
    host = simulate_full(
        Scenario(model, P, n * P.dt, 2, 5, amplitude=1e-3), body=RigidBody(backend=_cpu_backend())
    )
    dev = _device_control_errors(model, n, 1e-3, 5)
    assert dev.shape == host["balancing_error"].shape
    assert _rel(dev, host["balancing_error"]) < 1e-5


def test_points_packed_in_one_batch_equal_separate_batches() -> None:
    """Two rod lengths as one batch (per-world model fields) give each point's own run."""
    from cip.engines.warp import point_control
    from cip.engines.warp_batch import WarpBatch
    from cip.model import CIPParams, build

    d = P.delay_steps
    phys = [CIPParams.from_reduced(P, rod_length=r) for r in (0.3, 1.2)]
    models = [build("coupled", p) for p in phys]
    ctls = [point_control(P, p, a) for p, a in zip(phys, (1e-3, 2e-3), strict=True)]
    xi = GainNoise(9, 4, 2).next_chunk(2 * d)
    packed = WarpBatch(models, ctls, 2, 2, "cpu", max_chunk=d, every=10)
    # world w = realisation w // 2 of point w % 2
    world_xi = np.empty_like(xi)
    world_xi[0::2], world_xi[1::2] = xi[:2], xi[2:]
    got = np.concatenate([packed.advance(world_xi[:, k : k + d]) for k in (0, d)], axis=1)
    for p in range(2):
        alone = WarpBatch([models[p]], [ctls[p]], 2, 2, "cpu", max_chunk=d, every=10)
        mine = xi[2 * p : 2 * p + 2]
        want = np.concatenate([alone.advance(mine[:, k : k + d]) for k in (0, d)], axis=1)
        np.testing.assert_array_equal(got[p::2], want)


@pytest.mark.skipif("not _cuda()", reason="requires a CUDA device (CUDA graph capture)")
def test_cuda_graph_chunk_equals_plain_launches() -> None:
    """A delay chunk replayed as a CUDA graph gives what step-by-step launches give."""
    from cip.engines.warp import point_control
    from cip.engines.warp_batch import WarpBatch
    from cip.model import CIPParams, build

    phys = CIPParams.from_reduced(P)
    ctl = point_control(P, phys, 1e-3)
    d = P.delay_steps
    xi = GainNoise(1, 64, 2).next_chunk(3 * d)
    graph = WarpBatch([build("coupled", phys)], [ctl], 64, 2, "cuda:0", max_chunk=d)
    plain = WarpBatch([build("coupled", phys)], [ctl], 64, 2, "cuda:0", max_chunk=d)
    plain.chunks.cuda = False
    for k in range(0, 3 * d, d):
        np.testing.assert_array_equal(graph.advance(xi[:, k : k + d]),
                                      plain.advance(xi[:, k : k + d]))  # fmt: skip


def test_packed_gpu_sweep_gives_the_cpu_sweep_results() -> None:
    """Two rod lengths x 2 realisations in one batch: same keys as evaluate_point and,
    point by point, the CPU MuJoCo sweep's numbers within float32 precision."""
    from validation.sweep import Study, evaluate_point
    from validation.sweeps.gpu import evaluate_points

    study = Study(name="t", model="coupled", realizations=2, duration=0.5, decimate=5,
                  metrics=("rms", "max_angle", "agreement"),
                  grid={"rod_length_ratio": [1.0, 2.0]})  # fmt: skip
    sd = study.as_dict()
    points = study.points()
    got = evaluate_points(sd, points, device="cpu")
    for point, res in zip(points, got, strict=True):
        want = evaluate_point(sd, point)
        assert set(res) == set(want)
        assert res["seed"] == want["seed"] and res["diverged"] == want["diverged"]
        np.testing.assert_allclose(res["rms"], want["rms"], atol=1e-5)
        np.testing.assert_allclose(res["max_angle"], want["max_angle"], rtol=1e-5)
        np.testing.assert_allclose(res["agreement"], want["agreement"], atol=1e-4)
