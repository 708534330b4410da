"""The constraint stages a model cannot use, off while cipval steps it (cip.mjstages)."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from cip.lyapunov import lyapunov_full
from cip.mjstages import unused_stage_flags
from cip.model import CIPParams, build
from cip.runner import MujocoRollout, RigidBody
from cip.simulate import simulate_full
from cipcore.params import BalanceParams
from cipcore.scenario import Execution, Recording, Scenario

D = mujoco.mjtDisableBit
FIELDS = ("balancing_error", "tip_velocity", "base_velocity", "angle")


class EveryStage(MujocoRollout):
    """MuJoCo's whole pipeline, as the model file asks."""

    skip_unused_stages = False


def test_each_shipped_model_loses_only_the_stage_it_cannot_use():
    single = build("single", CIPParams())
    coupled = build("coupled", CIPParams())
    assert unused_stage_flags(single) == D.mjDSBL_CONSTRAINT  # no constraint at all
    assert unused_stage_flags(coupled) == D.mjDSBL_ISLAND  # the rod: one island, every dof
    assert single.opt.disableflags & D.mjDSBL_CONSTRAINT == 0  # the model is not edited


@pytest.mark.parametrize(
    "edit",
    [
        lambda m: m.jnt_limited.__setitem__(0, 1),  # a joint limit: rows come and go
        lambda m: m.dof_frictionloss.__setitem__(0, 0.1),  # friction loss
        lambda m: setattr(m.opt, "disableflags", m.opt.disableflags & ~int(D.mjDSBL_CONTACT)),
    ],
    ids=["limit", "frictionloss", "contacts"],
)
@pytest.mark.parametrize("model", ["single", "coupled"])
def test_state_dependent_constraints_keep_every_stage(model, edit):
    m = build(model, CIPParams())
    edit(m)
    assert unused_stage_flags(m) == 0


def test_a_rod_switched_off_keeps_every_stage():
    """The equality disabled (the rod-removed fault): no island, nothing to skip, and the
    constraint stage stays (the model has an equality)."""
    m = build("coupled", CIPParams())
    m.opt.disableflags |= D.mjDSBL_EQUALITY
    assert unused_stage_flags(m) == 0


@pytest.mark.parametrize("amplitude", [1e-3, 0.1])
@pytest.mark.parametrize("model", ["single", "coupled"])
def test_states_are_bit_identical_with_every_stage(model, amplitude):
    """The delayed random-gain controller, 4 realisations x 3 s, inside and beyond the
    small-angle regime: every recorded field the same bit for bit."""
    p = BalanceParams(beta=21.032)
    scn = Scenario(model, p, 3.0, 4, 11, amplitude=amplitude)
    kw = {"recording": Recording(fields=FIELDS), "execution": Execution(threads=2)}
    skipped = simulate_full(scn, **kw)
    every = simulate_full(scn, body=RigidBody(backend=EveryStage), **kw)
    for f in FIELDS:
        np.testing.assert_array_equal(skipped[f], every[f], err_msg=f)


@pytest.mark.parametrize("model", ["single", "coupled"])
def test_lambda1_is_bit_identical_with_every_stage(model):
    p = BalanceParams(beta=21.5)
    a = lyapunov_full(Scenario(model, p, 5.0, 2, 4))
    b = lyapunov_full(Scenario(model, p, 5.0, 2, 4), body=RigidBody(backend=EveryStage))
    np.testing.assert_array_equal(a.per_realization, b.per_realization)


@pytest.mark.parametrize("model", ["single", "coupled"])
def test_a_rollout_on_threads_keeps_one_pool_and_the_one_thread_states(model, monkeypatch):
    """MujocoRollout on 2 threads starts one thread pool for all its calls (not one per
    call, as ``mujoco.rollout.rollout`` does), and every step's state is the one of a
    single thread's rollout, bit for bit."""
    from mujoco import rollout

    if not hasattr(rollout, "Rollout"):
        pytest.skip("mujoco.rollout.Rollout needs MuJoCo >= 3.3.1")
    started = []
    real = rollout.Rollout.__init__
    monkeypatch.setattr(rollout.Rollout, "__init__",
                        lambda self, **kw: started.append(kw) or real(self, **kw))  # fmt: skip
    m = build(model, CIPParams())
    spec = mujoco.mjtState.mjSTATE_FULLPHYSICS
    d = mujoco.MjData(m)
    d.qpos[:] = 0.05
    s0 = np.empty(mujoco.mj_stateSize(m, spec))
    mujoco.mj_getState(m, d, s0, spec)
    ctrl = np.random.default_rng(3).standard_normal((5, 40, m.nu))
    got = {}
    for threads in (1, 2):
        backend = MujocoRollout(m, 5, threads)
        state, chunks = np.tile(s0, (5, 1)), []
        for k in range(0, 40, 10):  # four calls
            out = np.empty((5, 10, s0.size))
            backend(state, ctrl[:, k : k + 10], out)
            state = out[:, -1].copy()
            chunks.append(out)
        got[threads] = np.concatenate(chunks, axis=1)
    assert started == [{"nthread": 0}, {"nthread": 2}]
    np.testing.assert_array_equal(got[1], got[2])
    assert np.abs(got[1][:, -1] - got[1][:, 0]).max() > 1e-6  # the states moved
