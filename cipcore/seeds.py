"""The seed namespace: which random stream each use of a seed draws from.

A root seed fixes every random number in the suite.  Realisation ``r``'s
feedback-gain noise is ``SeedSequence(seed, spawn_key=(r,))`` (see
:mod:`cipcore.noise`).  Every other use of the same root seed (initial tangent
vectors of the Lyapunov estimate, bootstrap resampling, bot subjects ...) draws
from a key that no realisation can reach: its first element is
``PURPOSE_BASE + purpose`` with ``PURPOSE_BASE = 2**32``, above any realisation
index (realisation counts are capped at 2**32 by :func:`check_realization`).

The initial tangent vector of realisation ``r``'s Lyapunov estimate (both
engines) is ``SeedSequence(seed, spawn_key=(r, 1))``: a child of the
realisation's own key, so it too is reproducible for any batch split and
distinct from every noise stream.

Adding a purpose is one line in :data:`PURPOSES`.
"""

from __future__ import annotations

import numpy as np

from .params import ParameterError

PURPOSE_BASE = 2**32

#: Random uses other than the noise of a realisation, each with its own stream.
PURPOSES: dict[str, int] = {
    "bootstrap": 1,
    "bot": 2,
    "selftest": 3,
    "refinement": 4,
}


def check_realization(index: int) -> int:
    """A realisation index in [0, 2**32)."""
    if not 0 <= int(index) < PURPOSE_BASE:
        raise ParameterError(f"realization index must be in [0, 2**32), got {index}")
    return int(index)


def noise_sequence(seed: int, realization: int) -> np.random.SeedSequence:
    """The feedback-gain noise stream of one realisation."""
    return np.random.SeedSequence(seed, spawn_key=(check_realization(realization),))


def tangent_rng(seed: int, realization: int) -> np.random.Generator:
    """The stream of realisation ``realization``'s initial tangent vector (lambda1)."""
    ss = np.random.SeedSequence(seed, spawn_key=(check_realization(realization), 1))
    return np.random.Generator(np.random.PCG64(ss))


def tangent_deviation(seed: int, realization: int, n_controllers: int,
                      delay_steps: int) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """A rigid body's initial Benettin deviation of one realisation, before its scaling.

    Returns (e0, history): e0 (C,) the balancing errors L theta_i (m, each angle a
    standard-normal draw over L), then history (d, C) the delayed errors at steps
    -d .. -1, from :func:`tangent_rng` in that order; carts and velocities start at 0.
    In the coupled model (C = 2) both angles start at their mean (on the rod's
    constraint to first order).  The engines' Benettin estimator
    (:func:`cip.lyapunov.lyapunov_full`) and their exact twins'
    (:func:`reduced.twin_lyapunov.lyapunov_twin`) start from it, so that realisation r
    of both follows the same deviation.
    """
    rng = tangent_rng(seed, realization)
    e0 = rng.standard_normal(n_controllers)
    history = rng.standard_normal((delay_steps, n_controllers))
    if n_controllers == 2:
        e0[:] = e0.mean()
    return e0, history


def purpose_rng(seed: int, purpose: str, *key: int) -> np.random.Generator:
    """A generator for ``purpose`` (a name in :data:`PURPOSES`), further keyed by ``key``."""
    if purpose not in PURPOSES:
        raise ParameterError(f"purpose must be one of {', '.join(PURPOSES)}, got {purpose!r}")
    ss = np.random.SeedSequence(seed, spawn_key=(PURPOSE_BASE + PURPOSES[purpose], *key))
    return np.random.Generator(np.random.PCG64(ss))
