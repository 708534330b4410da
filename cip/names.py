"""The CIP model's element names: the one place that spells them.

Balancer i = 1, 2 of the MJCF (:mod:`cip.model`, a user's file read by
:mod:`cip.mjcf_params`): the cart's slide joint, the pendulum's hinge, the tip
site (the bob), the motor carrying the control force, the affine-bias actuators
of the tip and cart damping; the rod is a spatial tendon and a tendon equality
of one name.
"""

from __future__ import annotations

#: Name of the rod's tendon and of its equality constraint (coupled model).
ROD = "rod"


def cart_joint(i: int) -> str:
    """Slide joint of cart i (qpos: the cart position x_M, m)."""
    return f"x_M{i}"


def hinge_joint(i: int) -> str:
    """Hinge joint of pendulum i (qpos: the angle theta, rad)."""
    return f"theta_{i}"


def tip_site(i: int) -> str:
    """Site at the tip of pendulum i (the bob's centre of mass)."""
    return f"tip_{i}"


def motor(i: int) -> str:
    """Motor on cart i carrying the control force F_i (N), gear 1."""
    return f"u_{i}"


def tip_damper(i: int) -> str:
    """Affine-bias actuator of the tip damping -gamma m v_tip (N)."""
    return f"tip_damping_{i}"


def cart_damper(i: int) -> str:
    """Affine-bias actuator of the cart damping -gamma M v_M (N)."""
    return f"cart_damping_{i}"
