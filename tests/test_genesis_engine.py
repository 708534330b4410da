"""The Genesis engine's own checks (skipped, with the reason, where genesis-world is absent).

Genesis takes every parameter of the model as the geometry states it (read back after
the build); its own MJCF parse of the shipped files is compared with that; a
realisation's numbers do not depend on the batch it is stepped in; an overflow stops
only its realisation.  Its refinement tier, Euler step, rod, faults and delay are held
with the other refinement-tier engines in tests/test_refinement_engines.py.  Genesis
compiles its kernels on the first scene of the process (22 s on a cold kernel cache,
10 s from a warm one, at load 4-5 on 2 cores), after 15-20 s of importing it
(``.ci/genesis`` runs these tests and the shared ones with ``-k genesis``).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

pytest.importorskip("genesis", reason="genesis-world is not installed (see .ci/genesis)")

from helpers import forced, roll, tip_stretch

from cip.engines.drake_plant import geometry_from_mujoco
from cip.engines.genesis import (
    PROBE_TOLERANCE,
    GenesisModelError,
    GenesisRollout,
    build_scene,
    verify_scene,
)
from cip.mjcf_params import shipped_model_path
from validation.checks.agreement import model_file


def _run(m, state: np.ndarray, ctrl: np.ndarray, n_envs: int) -> np.ndarray:
    """The states after each step, in two chunks, ``n_envs`` environments a scene."""
    return roll(GenesisRollout, m, state, ctrl, n_envs=n_envs)


@pytest.mark.parametrize("model", ["single", "coupled"])
def test_genesis_takes_the_model_as_stated(model: str) -> None:
    """Masses, inertias, zero damping/armature, gravity, dt: read back after the build;
    the unconstrained acceleration at a tilted, moving state is MuJoCo's to round-off."""
    m = model_file(model)
    c = build_scene(geometry_from_mujoco(m), 2)
    try:
        assert verify_scene(c, m) <= PROBE_TOLERANCE
    finally:
        c.scene.destroy()


def test_a_wrong_tip_mass_fails_the_probe() -> None:
    """A scene built with a 1e-3 error of the tip mass differs from the model file's
    MuJoCo acceleration at the probe state (the check has power)."""
    m = model_file("single")
    g = geometry_from_mujoco(m)
    c = build_scene(dataclasses.replace(g, bob_mass=(g.bob_mass[0] * 1.001,)), 1)
    try:
        with pytest.raises(GenesisModelError, match="probe state"):
            verify_scene(c, m)
    finally:
        c.scene.destroy()


def test_genesis_parses_the_shipped_single_file_alike_and_refuses_the_rod() -> None:
    """Genesis's own MJCF parse of the shipped single file takes the masses and centres of
    mass of the document the engine writes (its dampers and motor it leaves out: zero
    actuator gains and biases); the coupled file's rod (a tendon equality) it refuses."""
    import genesis as gs

    from cip.engines.genesis import _genesis, _numpy

    _genesis()
    g = geometry_from_mujoco(model_file("single"))
    options = gs.options.RigidOptions(enable_collision=False, disable_constraint=True)
    scene = gs.Scene(rigid_options=options, show_viewer=False)
    entity = scene.add_entity(
        gs.morphs.MJCF(file=str(shipped_model_path("single")), default_armature=None)
    )
    scene.build(n_envs=1)
    try:
        links = [entity.get_link(n).idx_local for n in ("cart_1", "pendulum_1")]
        np.testing.assert_array_equal(
            _numpy(entity.get_links_mass(links)).ravel(), [g.cart_mass[0], g.bob_mass[0]]
        )
        com = _numpy(entity.get_links_COM(links)).reshape(2, 3)
        np.testing.assert_array_equal(com[1], [0.0, 0.0, g.pendulum_length[0]])
        assert not _numpy(entity.get_dofs_act_gain()).any()
        assert not any(_numpy(b).any() for b in entity.get_dofs_act_bias())
    finally:
        scene.destroy()
    coupled = gs.Scene(rigid_options=options, show_viewer=False)
    with pytest.raises(gs.GenesisException, match="equality"):
        coupled.add_entity(gs.morphs.MJCF(file=str(shipped_model_path("coupled"))))
    coupled.destroy()


def test_rod_holds_and_a_realisation_ignores_its_batch() -> None:
    """Coupled model: the rod's stretch stays at the projection's curvature term, and
    realisation 0 is bit-identical stepped alone or with two others, in blocks of 3 or 2."""
    m, state, ctrl = forced("coupled", 3, 400)
    ctrl[1:] *= 2.0  # the batch neighbours move differently
    together = _run(m, state, ctrl, 3)
    alone = _run(m, state[:1], ctrl[:1], 1)
    blocks = _run(m, state, ctrl, 2)  # 3 realisations in blocks of 2 environments
    np.testing.assert_array_equal(together[0], alone[0])
    np.testing.assert_array_equal(together, blocks)
    assert np.abs(tip_stretch(m, together)).max() < 1e-9


def test_an_overflow_stops_its_realisation_only() -> None:
    """A force beyond MAXVAL (1e12 N) and a NaN start state end those realisations as NaN
    from the step they enter; the batch's other realisation steps as it does alone."""
    m, state, ctrl = forced("single", 3, 50)
    ctrl[1, 20:] = 1e12
    state[2, 2] = np.nan
    out = np.empty((*ctrl.shape[:2], state.shape[1]))
    backend = GenesisRollout(m, 3, 1)
    try:
        backend(state, ctrl, out)
        assert backend.warnings() == 1
    finally:
        backend.close()
    # (the time column of _run's two chunks rounds otherwise)
    np.testing.assert_array_equal(out[0, :, 1:], _run(m, state[:1], ctrl[:1], 1)[0, :, 1:])
    assert np.isfinite(out[1, :20]).all() and np.isnan(out[1, 20:, 1:]).all()
    assert np.isnan(out[2, :, 1:]).all()
