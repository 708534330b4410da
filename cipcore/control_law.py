"""The delayed random-gain control law, written once (paper eq. (5)).

The feedback on balancer i over step n is

    u_i(n) = beta * R_{i,n} * e_i(n - d),     R_{i,n} = 1 + noise_scale * xi_{i,n},

with d = tau/dt steps of delay, the random gain drawn at step n (not n - d),
noise_scale = nu / sqrt(dt) (dimensionless per unit draw) and the draws
xi ~ N(0, 1) of :mod:`cipcore.noise`; the single model's law (eq. (3)) is the
same with one balancer.  ``gain`` is beta (1/s^2) for the reduced models, whose
control is an acceleration, and M beta (N/m, M the cart mass in kg) for the
rigid-body CIP, whose control is a force.

The expression is evaluated as ``(gain * (1 + noise_scale * xi)) * e_delayed``,
in this order, wherever the law is applied: by numpy on whole chunks
(:mod:`cip.runner`) and, compiled by numba (:mod:`cipcore.control_kernel`),
inside the reduced models' kernels, so every engine and the reference apply
the same rounding.  The warp kernels (float64 in :mod:`reduced.gpu`, float32 in
:mod:`cip.engines.warp_batch`) cannot call Python; their copy is tested bit-equal to
this function.
"""

from __future__ import annotations

from typing import TypeVar

import numpy as np

Value = TypeVar("Value", float, np.ndarray)


def delayed_random_gain(gain: float, noise_scale: float, xi: Value, e_delayed: Value) -> Value:
    """The control u = gain * (1 + noise_scale * xi) * e(t - tau) (paper eq. (5)).

    Parameters
    ----------
    gain : beta (1/s^2) for an acceleration, M beta (N/m) for a force.
    noise_scale : nu / sqrt(dt), the random gain's spread per unit draw.
    xi : standard normal draw(s) of the current step.
    e_delayed : the balancing error (m) d = tau/dt steps earlier.

    Returns
    -------
    The control (m/s^2 or N), elementwise for arrays.
    """
    return gain * (1.0 + noise_scale * xi) * e_delayed
