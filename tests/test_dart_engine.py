"""The DART engine's own overflow handling (skipped, with the reason, where dartpy is
absent): a state that overflows is NaN from that step (DART itself would zero it and go
on).  Its refinement tier, Euler step, rod, faults and delay are held with the other
refinement-tier engines in tests/test_refinement_engines.py.
"""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("dartpy", reason="dartpy is not installed (pip install 'cipval[dart]')")

from helpers import forced

from cip.engines.dart import MAXVAL, DartRollout


def test_overflow_is_nan_from_its_step() -> None:
    """A force beyond MAXVAL, or a state driven beyond it: NaN from that step on, counted
    in ``warnings()``; the other realisations of the batch are untouched."""
    m, state, ctrl = forced("single", 3, 40)
    ctrl[:] = 0.0  # tilted 0.01 rad, unforced: realisation 0 falls slowly, finite
    ctrl[1, 10:] = np.inf
    ctrl[2, 5:] = 1e9  # the cart's velocity passes MAXVAL within the chunk
    out = np.empty((3, 40, state.shape[1]))
    backend = DartRollout(m, 3, 1)
    backend(state, ctrl, out)
    assert backend.warnings() == 2
    assert np.isfinite(out[0]).all()
    assert np.isfinite(out[1, :10]).all() and np.isnan(out[1, 10:, 1:]).all()
    first = int(np.argmax(np.isnan(out[2, :, 1])))
    assert 5 < first < 40 and np.isnan(out[2, first:, 1:]).all()
    assert np.abs(out[2, :first, 1:]).max() < MAXVAL
