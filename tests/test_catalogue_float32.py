"""The selftest catalogue of a float32 engine: sizes below its floor raised, with why."""

from __future__ import annotations

from dataclasses import replace

from cip.engines.rigid_body import MUJOCO
from validation.faults.catalogue import CATALOGUE, FLOAT32_SIZES, catalogue_sizes
from validation.faults.selftest import format_table

F64 = MUJOCO.capabilities
#: a float32 engine judged by refinement (no twin), and one judged by its twin
F32_REFINEMENT = replace(F64, precision="float32", twin=None)
F32_TWIN = replace(F64, precision="float32")


def test_float64_and_twin_judged_engines_keep_the_catalogue_sizes():
    for caps in (None, F64, F32_TWIN, replace(F64, twin=None)):
        assert [(k, s) for k, s, _ in catalogue_sizes(caps)] == list(CATALOGUE)
        assert all(why == "" for _, _, why in catalogue_sizes(caps))


def test_float32_refinement_engines_get_the_raised_sizes_and_the_reason():
    sizes = {k: (s, why) for k, s, why in catalogue_sizes(F32_REFINEMENT)}
    assert set(sizes) == {k for k, _ in CATALOGUE}
    for kind, (size, why) in FLOAT32_SIZES.items():
        assert sizes[kind] == (size, why) and size > dict(CATALOGUE)[kind] and "float32" in why
    unchanged = [k for k in sizes if k not in FLOAT32_SIZES]
    assert all(sizes[k][0] == dict(CATALOGUE)[k] and not sizes[k][1] for k in unchanged)


def test_the_selftest_table_states_a_raised_size():
    row = {"fault": "bob_inertia", "size": 1e-2, "unit": "kappa", "flagged": True,
           "by": ["refinement.single"], "size_note": FLOAT32_SIZES["bob_inertia"][1]}  # fmt: skip
    assert "raised from 1e-4 for float32" in format_table([], [row])
