"""The control law of :mod:`cipcore.control_law` as a warp function (paper eq. (5)).

Warp kernels cannot call Python or numba, so the law is written here once more,
as a generic ``wp.func`` used by both warp kernels: float64 in
:mod:`reduced.gpu`, float32 in :mod:`cip.engines.warp_batch`.  It evaluates
``(gain * (1 + noise_scale * xi)) * e_delayed`` in the same order as
:func:`cipcore.control_law.delayed_random_gain`, and the tests check it
bit-equal to that function on warp's CPU device in both precisions.  Needs
``warp-lang`` (``pip install 'cipval[warp]'``); only the warp engines import it.
"""

from __future__ import annotations

from typing import Any

import warp as wp


@wp.func
def delayed_random_gain(gain: Any, noise_scale: Any, xi: Any, e_delayed: Any):
    """u = gain * (1 + noise_scale * xi) * e(t - tau), in the precision of ``gain``."""
    return gain * (type(gain)(1.0) + noise_scale * xi) * e_delayed
