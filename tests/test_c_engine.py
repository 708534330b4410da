"""The engine in plain C (examples/c_engine): built with the system's compiler, driven over
the chunk exchange protocol directly and through `cip-validate contract` / `run`."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import mujoco
import numpy as np
import pytest
from mujoco import rollout

from cip.engines.process import header
from cip.mjcf_params import load_model_file, shipped_model_path

SOURCE = Path(__file__).resolve().parent.parent / "examples" / "c_engine" / "cip_engine.c"
#: the Makefile's flags
CFLAGS = ["-O2", "-std=c11", "-Wall", "-Wextra", "-Werror"]
I64, F64 = np.dtype("<i8"), np.dtype("<f8")
FULL = mujoco.mjtState.mjSTATE_FULLPHYSICS
#: relative L2 distance of the C engine to mujoco.rollout (Euler) on the single model:
#: measured 2.8e-16 (the same scheme, another order of operations), max abs 1.8e-15
SINGLE_TOLERANCE = 1e-12
#: the coupled model: the C engine's rigid rod against MuJoCo's soft rod (solref 2 ms),
#: measured 5.3e-7 relative; the C engine's rod holds to 1.6e-11 m (MuJoCo's: 1.5e-8 m)
COUPLED_TOLERANCE, ROD_TOLERANCE = 1e-5, 1e-9


@pytest.fixture(scope="module")
def engine(tmp_path_factory) -> Path:
    """The engine built from source into a temporary folder (nothing left in the tree)."""
    cc = shutil.which("cc")
    if cc is None:
        pytest.skip("no C compiler: `cc` is not on PATH (the C engine cannot be built)")
    exe = tmp_path_factory.mktemp("c_engine") / "cip_engine"
    build = subprocess.run([cc, *CFLAGS, "-o", str(exe), str(SOURCE), "-lm"],
                           capture_output=True, text=True)  # fmt: skip
    assert build.returncode == 0, build.stderr
    return exe


class Session:
    """One engine process driven by hand: header, frames, n = 0."""

    def __init__(self, argv: list[str]) -> None:
        self.proc = subprocess.Popen(argv, stdin=subprocess.PIPE, stdout=subprocess.PIPE)

    def start(self, head: dict) -> dict:
        self.proc.stdin.write((json.dumps(head) + "\n").encode())
        self.proc.stdin.flush()
        self.head = head
        return json.loads(self.proc.stdout.readline())

    def chunk(self, state: np.ndarray, ctrl: np.ndarray) -> tuple[int, np.ndarray]:
        r, n, _ = ctrl.shape
        s = self.head["nstate"]
        self.proc.stdin.write(np.array([n], I64).tobytes() + state.astype(F64).tobytes()
                              + np.ascontiguousarray(ctrl, F64).tobytes())  # fmt: skip
        self.proc.stdin.flush()
        want = 8 + r * n * s * 8
        data = self.proc.stdout.read(want)
        assert len(data) == want
        return int(np.frombuffer(data[:8], I64)[0]), np.frombuffer(data[8:], F64).reshape(r, n, s)

    def run(self, state: np.ndarray, ctrl: np.ndarray, chunk: int) -> np.ndarray:
        """States after every step of ``ctrl`` (R, n, U), in chunks of ``chunk`` steps."""
        out = []
        for k in range(0, ctrl.shape[1], chunk):
            _, states = self.chunk(state, ctrl[:, k : k + chunk])
            out.append(states)
            state = states[:, -1]
        return np.concatenate(out, axis=1)

    def end_session(self) -> None:
        self.proc.stdin.write(np.zeros(1, I64).tobytes())
        self.proc.stdin.flush()

    def close(self) -> int:
        self.proc.stdin.close()
        return self.proc.wait(timeout=10)


def _open_loop(kind: str, n_realizations: int, n_steps: int, seed: int, tilt: float = 0.02):
    """The model, start states tilted by up to ``tilt`` rad at rest, smooth motor forces
    (R, n, nu)."""
    model = load_model_file(shipped_model_path(kind))
    data = mujoco.MjData(model)
    mujoco.mj_resetData(model, data)
    mujoco.mj_forward(model, data)
    s0 = np.empty(mujoco.mj_stateSize(model, FULL))
    mujoco.mj_getState(model, data, s0, FULL)
    rng = np.random.default_rng(seed)
    state = np.tile(s0, (n_realizations, 1))
    nc = 1 if kind == "single" else 2
    ctrl = np.zeros((n_realizations, n_steps, model.nu))
    t = np.arange(n_steps) * model.opt.timestep
    tilts = rng.uniform(-tilt, tilt, n_realizations)
    for i in range(nc):
        th = 1 + model.jnt_qposadr[mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT,
                                                     f"theta_{i + 1}")]  # fmt: skip
        state[:, th] = tilts  # the same tilt for both pendula: the rod's length holds
        amp = rng.normal(0, 0.5, (n_realizations, 1))
        freq = rng.uniform(0.5, 3, (n_realizations, 1))
        ctrl[:, :, i] = amp * np.sin(2 * np.pi * freq * t)
    return model, data, state, ctrl


def _relative(a: np.ndarray, b: np.ndarray, start: np.ndarray) -> float:
    return float(np.linalg.norm(a - b) / np.linalg.norm(b - start[:, None]))


def test_single_model_matches_mujoco_euler_and_the_rod_holds(engine):
    """The C engine against MuJoCo's own semi-implicit Euler (mujoco.rollout): the same
    scheme on the single model (round-off apart), 1 s open loop, 3 realisations, chunks of
    100 steps, the pendula far from upright; on the coupled model its rigid rod keeps the tips
    at the rod's length and stays near MuJoCo's soft rod.  Two sessions in one process."""
    eng = Session([str(engine)])
    try:
        for kind in ("single", "coupled"):
            # single: tilts up to 1.2 rad, far from upright (the nonlinear terms)
            tilt = 1.2 if kind == "single" else 0.02
            model, data, state, ctrl = _open_loop(kind, 3, 1000, seed=4, tilt=tilt)
            answer = eng.start(header(model, 3))
            assert answer == {"protocol": "cipval-chunk", "version": 2, "engine": "c-engine",
                              "integrator": "other", "order": 1, "rod": "rigid",
                              "sessions": "many"}  # fmt: skip
            got = eng.run(state, ctrl, 100)
            eng.end_session()
            ref, _ = rollout.rollout(model, data, state, ctrl)
            np.testing.assert_allclose(got[..., 0], ref[..., 0], rtol=0, atol=1e-12)  # time
            q = slice(1, 1 + model.nq + model.nv)
            dist = _relative(got[..., q], ref[..., q], state[:, q])
            if kind == "single":
                assert dist < SINGLE_TOLERANCE, dist
                continue
            assert dist < COUPLED_TOLERANCE, dist
            geo = header(model, 1)["parameters"]
            tips = [
                np.stack([geo["cart_x0"][i] + got[..., 1 + geo["qpos_x"][i]]
                          + geo["pendulum_length"][i] * np.sin(got[..., 1 + geo["qpos_theta"][i]]),
                          geo["pendulum_length"][i] * np.cos(got[..., 1 + geo["qpos_theta"][i]])],
                         axis=-1)
                for i in range(2)
            ]  # fmt: skip
            stretch = np.linalg.norm(tips[0] - tips[1], axis=-1) - geo["rod_length"]
            assert np.abs(stretch).max() < ROD_TOLERANCE
    finally:
        assert eng.close() == 0  # its stdin ended: no further session


def test_delay_fault_applies_each_control_one_step_late(engine):
    """--fault delay over two chunks is the clean engine under the controls shifted by one
    step (0 first); its handshake names the fault."""
    model, _, state, ctrl = _open_loop("single", 2, 60, seed=2)
    shifted = np.concatenate([np.zeros_like(ctrl[:, :1]), ctrl[:, :-1]], axis=1)
    clean, late = Session([str(engine)]), Session([str(engine), "--fault", "delay"])
    try:
        clean.start(header(model, 2))
        assert late.start(header(model, 2))["engine"] == "c-engine-delay"
        assert np.array_equal(late.run(state, ctrl, 25), clean.run(state, shifted, 25))
    finally:
        clean.close()
        late.close()


def test_handshake_versions_refusals_and_warnings(engine):
    model = load_model_file(shipped_model_path("single"))
    head = header(model, 1)
    eng = Session([str(engine), "--one-session"])
    v1 = {k: v for k, v in head.items() if k != "versions"}
    assert eng.start(v1) == {"protocol": "cipval-chunk", "version": 1, "engine": "c-engine"}
    state = np.full((1, head["nstate"]), np.nan)
    warnings, out = eng.chunk(state, np.zeros((1, 3, head["nu"])))
    assert warnings == 3 and np.isnan(out[..., 1:]).all()
    eng.end_session()
    assert eng.close() == 0
    for bad in ({**head, "version": 3}, {**head, "protocol": "other"},
                {**head, "parameters": {**head["parameters"], "cart_mass": []}}):  # fmt: skip
        eng = Session([str(engine), "--fault", "length"])
        assert "error" in eng.start(bad)
        assert eng.proc.wait(timeout=10) == 1


def _cli(*args: str, timeout: float) -> subprocess.CompletedProcess:
    env = {**os.environ, "MPLBACKEND": "Agg"}
    return subprocess.run([sys.executable, "-m", "validation.cli.main", *args],
                          capture_output=True, text=True, timeout=timeout, env=env)  # fmt: skip


def _contract(engine: Path, fault: str | None) -> tuple[int, dict]:
    cmd = str(engine) + (f" --fault {fault}" if fault else "")
    res = _cli("contract", "--engine-cmd", cmd, "--json", timeout=120)
    return res.returncode, {r["check"]: r["status"] for r in json.loads(res.stdout)["checks"]}


def test_contract_passes_for_the_c_engine(engine):
    res = _cli("contract", "--engine-cmd", str(engine), "--quiet", timeout=120)
    assert res.returncode == 0, res.stdout + res.stderr


@pytest.mark.parametrize(("fault", "caught_by"), [("delay", "delay"), ("length", "rod")])
def test_contract_fails_for_each_fault(engine, fault, caught_by):
    """The one-step delay fails `delay` (the lag); the pendulum 0.5 % long fails `rod` (the
    tips, placed by cipval at the file's length, drift apart).  `run` catches the length
    by refinement (the slow test below)."""
    code, status = _contract(engine, fault)
    assert code == 1 and status[caught_by] == "fail", status


@pytest.mark.slow
@pytest.mark.parametrize(
    ("fault", "failing"),
    [(None, set()),
     ("length", {"refinement.single", "refinement.coupled",
                 "closed_loop.single", "closed_loop.coupled"}),
     ("delay", {"delay.single", "delay.coupled"})],
)  # fmt: skip
def test_smoke_run_passes_and_catches_each_fault(engine, tmp_path, fault, failing):
    """`cip-validate run --profile smoke` (about 15 s each): the clean engine passes, judged
    by refinement (the twin checks n/a); each fault fails its checks.  The long pendulum
    moves both refinement limits (open and closed loop); the one-step lag does not (at a
    step of h/k it is a lag of h/k, gone in the limit), so only `delay` sees it."""
    cmd = str(engine) + (f" --fault {fault}" if fault else "")
    out = tmp_path / "run"
    res = _cli("run", "--engine-cmd", cmd, "--profile", "smoke", "--no-figures", "--quiet",
               "--out", str(out), timeout=600)  # fmt: skip
    assert res.returncode == (1 if failing else 0), res.stdout + res.stderr
    doc = json.loads((out / "results.json").read_text())
    status = {r["name"]: r["status"] for r in doc["checks"]}
    assert {n for n, s in status.items() if s == "fail"} == failing
    assert status["refinement.single"] == ("fail" if fault == "length" else "pass")
