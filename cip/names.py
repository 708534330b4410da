"""The CIP model's element names: the one place that spells them.

Balancer i = 1, 2 of the MJCF (:mod:`cip.model`, a user's file read by
:mod:`cip.mjcf_params`): the cart's slide joint, the pendulum's hinge, the tip
site (the bob), the motor carrying the control force, the affine-bias actuators
of the tip and cart damping; the rod is a spatial tendon and a tendon equality
of one name.  ``i`` is the balancer's index, or a placeholder such as
``"<i>"`` in a message naming the pattern.
"""

from __future__ import annotations

from collections.abc import Callable

#: Name of the rod's tendon and of its equality constraint (coupled model).
ROD = "rod"
#: The balancers' indices i in a model of one or two balancers.
BALANCERS = (1, 2)


def every_balancer(name_of: Callable[[int], str]) -> frozenset[str]:
    """The names of one kind (``name_of``, e.g. :func:`cart_joint`) for i = 1, 2."""
    return frozenset(name_of(i) for i in BALANCERS)


def cart_body(i: int | str) -> str:
    """Body of cart i (mass M, kg), child of the world."""
    return f"cart_{i}"


def pendulum_body(i: int | str) -> str:
    """Body of pendulum i, child of cart i: the hinge, the pole and the bob."""
    return f"pendulum_{i}"


def cart_joint(i: int | str) -> str:
    """Slide joint of cart i (qpos: the cart position x_M, m)."""
    return f"x_M{i}"


def hinge_joint(i: int | str) -> str:
    """Hinge joint of pendulum i (qpos: the angle theta, rad)."""
    return f"theta_{i}"


def tip_site(i: int | str) -> str:
    """Site at the tip of pendulum i (the bob's centre of mass)."""
    return f"tip_{i}"


def motor(i: int | str) -> str:
    """Motor on cart i carrying the control force F_i (N), gear 1."""
    return f"u_{i}"


def tip_damper(i: int | str) -> str:
    """Affine-bias actuator of the tip damping -gamma m v_tip (N)."""
    return f"tip_damping_{i}"


def cart_damper(i: int | str) -> str:
    """Affine-bias actuator of the cart damping -gamma M v_M (N)."""
    return f"cart_damping_{i}"


def pole_geom(i: int | str) -> str:
    """Capsule drawn from hinge i to the tip (no mass, no contact)."""
    return f"pole_{i}"


def bob_geom(i: int | str) -> str:
    """Sphere drawn at tip i (no mass, no contact)."""
    return f"bob_{i}"
