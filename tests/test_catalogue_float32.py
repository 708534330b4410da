"""The selftest catalogue of a float32 engine: sizes below its floor raised, with why."""

from __future__ import annotations

from validation.faults.catalogue import CATALOGUE, FLOAT32_SIZES, catalogue_sizes
from validation.faults.selftest import format_table


def test_float64_engines_keep_the_catalogue_sizes():
    assert [(k, s) for k, s, _ in catalogue_sizes("float64")] == list(CATALOGUE)
    assert all(why == "" for _, _, why in catalogue_sizes("float64"))


def test_float32_engines_get_the_raised_sizes_and_the_reason():
    sizes = {k: (s, why) for k, s, why in catalogue_sizes("float32")}
    assert set(sizes) == {k for k, _ in CATALOGUE}
    for kind, (size, why) in FLOAT32_SIZES.items():
        assert sizes[kind] == (size, why) and size > dict(CATALOGUE)[kind] and "float32" in why
    unchanged = [k for k in sizes if k not in FLOAT32_SIZES]
    assert all(sizes[k][0] == dict(CATALOGUE)[k] and not sizes[k][1] for k in unchanged)


def test_the_selftest_table_states_a_raised_size():
    row = {"fault": "bob_inertia", "size": 1e-2, "unit": "kappa", "flagged": True,
           "by": ["refinement.single"], "size_note": FLOAT32_SIZES["bob_inertia"][1]}  # fmt: skip
    assert "raised from 1e-4 for float32" in format_table([], [row])
