"""The Newton engine's own check (skipped, with the reason, where newton is absent): its
rigid rod against MuJoCo's soft one.  Its refinement tier, Euler step, rod, faults and
delay are held with the other refinement-tier engines in tests/test_refinement_engines.py.
The first test in a process loads warp's compiled kernels (24 s of CPU once per machine
to compile them, then about 3 s from warp's kernel cache).
"""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

pytest.importorskip("newton", reason="newton is not installed (pip install 'cipval[newton]')")

from helpers import forced, roll

from cip.engines.newton import NewtonRollout

#: warp kernels on warp's CPU device: CI's warp step runs them in one process (-n 0), so
#: that warp compiles Newton's kernels once
pytestmark = pytest.mark.warp


def test_coupled_positions_follow_mujocos_soft_rod() -> None:
    """The coupled model's positions follow MuJoCo's soft rod to its softness and float32
    rounding (measured 2e-7, relative L2, over 0.5 s of forcing)."""
    from mujoco import rollout

    m, state, ctrl = forced("coupled", 2, 500)
    out = roll(NewtonRollout, m, state, ctrl)
    ref, _ = rollout.rollout(m, mujoco.MjData(m), state, ctrl)
    pos = slice(1, 1 + m.nq)
    assert np.linalg.norm(out[..., pos] - ref[..., pos]) / np.linalg.norm(ref[..., pos]) < 2e-6
