"""The control law, the delay ring and the recording rule for the CPU kernels (numba).

Every compiled kernel (:mod:`reduced`'s positions, errors, nonlinear-stick,
twin and beta* kernels) calls these helpers, inlined by numba, so the convention
exists once:

* the law: :func:`cipcore.control_law.delayed_random_gain` compiled unchanged
  (paper eq. (5); eq. (3) with one balancer);
* the delay: a ring of the last d = tau/dt balancing errors per balancer.  At
  step n the slot ``p`` holds e at step n - d; :func:`ring_exchange` reads it,
  then overwrites it with e at step n, and :func:`ring_next` moves to the next
  slot (so the slot of step n is n mod d when the ring starts at slot 0 at
  step 0);
* the delayed control of one balancer over step n, the two together:
  :func:`delayed_control` = the law applied to :func:`ring_exchange`'s e(n - d);
* the recording: a sample is taken *before* every step whose global index is a
  multiple of ``every``; sample j of a call starting at step n0 holds step
  ``(first_sample(n0, every) + j) * every``.

The ring and recording helpers use no numba-only construct and no float
literal, so the warp kernel of :mod:`reduced.gpu` compiles the same Python
functions (``.py_func``) with ``wp.func``; the law needs a typed literal there
and has its warp copy in :mod:`cipcore.control_warp`.

numba caches a kernel by its own file only: after editing this module, clear
the ``__pycache__`` of the kernels' modules (or touch them) to recompile.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numba import njit

from .control_law import delayed_random_gain as _law

#: the law of :mod:`cipcore.control_law`, compiled for the kernels (inlined)
delayed_random_gain = njit(inline="always", cache=True, nogil=True)(_law)


@njit(inline="always", cache=True, nogil=True)
def ring_exchange(ring: Any, p: int, e: Any) -> Any:
    """Return e(n - d) from slot ``p`` of a balancer's ring (d,) and store e(n) there.

    ``ring`` a float array, ``e`` a float (m), annotated ``Any`` so that warp
    instantiates the function in the kernel's precision.
    """
    e_delayed = ring[p]
    ring[p] = e
    return e_delayed


@njit(inline="always", cache=True, nogil=True)
def delayed_control(
    ring: np.ndarray, p: int, e: float, gain: float, noise_scale: float, xi: float
) -> float:
    """The control over step n of one balancer: u = gain * (1 + noise_scale * xi) * e(n - d).

    Parameters
    ----------
    ring : (d,) the balancer's delay ring; slot ``p`` holds e(n - d) and receives
        ``e``, the balancing error at step n (:func:`ring_exchange`).
    gain, noise_scale, xi : as in :func:`cipcore.control_law.delayed_random_gain`
        (beta in 1/s^2 for an acceleration; nu / sqrt(dt); the draw of step n).

    Returns
    -------
    The control (paper eq. (5)), evaluated as that function evaluates it.
    """
    return delayed_random_gain(gain, noise_scale, xi, ring_exchange(ring, p, e))


@njit(inline="always", cache=True, nogil=True)
def ring_next(p: int, d: int) -> int:
    """The slot after ``p`` in a ring of d slots."""
    p += 1
    if p == d:
        p = 0
    return p


@njit(inline="always", cache=True, nogil=True)
def first_sample(n0: int, every: int) -> int:
    """Global index (in samples) of the first sample at or after step ``n0``."""
    return (n0 + every - 1) // every


@njit(inline="always", cache=True, nogil=True)
def sample_slot(nk: int, every: int, rec_start: int, nrec: int) -> int:
    """Row of ``rec`` that records the state before global step ``nk``, or -1 for none.

    ``rec_start`` is :func:`first_sample` of the call, ``nrec`` the rows it holds.
    """
    if nk % every != 0:
        return -1
    j = nk // every - rec_start
    return j if j < nrec else -1
