"""Relative edits of the compiled CIP's physical parameters, in place, by element name.

One edit per parameter of the paper's model that the model file carries: the tip mass
m (with the bob's inertia, so that m/M and the bob's radius of gyration stay as they
scale), the pendulum length L (hinge to bob and hinge to tip), gravity g and the two
dampers' coefficients gamma (the cart's and the tip's).  Each scales its parameter by
a factor; the caller runs :func:`mujoco.mj_setConst` afterwards where MuJoCo's derived
constants matter.  Used by the fault catalogue (:mod:`validation.faults.catalogue`:
the engine given a wrong parameter) and by the refinement check's projection
(:mod:`validation.checks.refinement`: the exact solution's sensitivity to each
parameter).
"""

from __future__ import annotations

from collections.abc import Callable

import mujoco

from cip.names import cart_damper, hinge_joint, tip_damper, tip_site

__all__ = [
    "PARAMETER_EDITS",
    "element_ids",
    "pendulum_bodies",
    "scale_damper",
    "scale_gravity",
    "scale_length",
    "scale_tip_mass",
]


def element_ids(m: mujoco.MjModel, kind: mujoco.mjtObj, name_of: Callable[[int], str]) -> list[int]:
    """Ids of balancer 1's and (where the model has it) balancer 2's element ``name_of(i)``."""
    out = []
    for i in (1, 2):
        j = mujoco.mj_name2id(m, kind, name_of(i))
        if j >= 0:
            out.append(j)
    return out


def pendulum_bodies(m: mujoco.MjModel) -> list[int]:
    """Body ids of each balancer's pendulum (the bodies of the hinge joints)."""
    return [m.jnt_bodyid[j] for j in element_ids(m, mujoco.mjtObj.mjOBJ_JOINT, hinge_joint)]


def scale_gravity(m: mujoco.MjModel, factor: float) -> None:
    """g (m/s^2) times ``factor``."""
    m.opt.gravity[2] *= factor


def scale_length(m: mujoco.MjModel, factor: float) -> None:
    """L (m) times ``factor``: the bob's position and the tip site on each pendulum.  The
    tip damper's force is -gamma m v, so its coefficient does not depend on L."""
    for b in pendulum_bodies(m):
        m.body_ipos[b] *= factor
    for s in element_ids(m, mujoco.mjtObj.mjOBJ_SITE, tip_site):
        m.site_pos[s] *= factor


def scale_tip_mass(m: mujoco.MjModel, factor: float) -> None:
    """The tip mass m (kg) times ``factor``, its inertia with it (m/M scales too)."""
    for b in pendulum_bodies(m):
        m.body_mass[b] *= factor
        m.body_inertia[b] *= factor


def scale_damper(m: mujoco.MjModel, name_of: Callable[[int], str], factor: float) -> None:
    """The damping actuators ``name_of(i)``'s coefficient (their velocity bias) times
    ``factor``."""
    for a in element_ids(m, mujoco.mjtObj.mjOBJ_ACTUATOR, name_of):
        m.actuator_biasprm[a][2] *= factor


#: parameter -> edit(m, factor), in the fault catalogue's kinds
PARAMETER_EDITS: dict[str, Callable[[mujoco.MjModel, float], None]] = {
    "mass_ratio": scale_tip_mass,
    "pendulum_length": scale_length,
    "gravity": scale_gravity,
    "tip_damping": lambda m, f: scale_damper(m, tip_damper, f),
    "cart_damping": lambda m, f: scale_damper(m, cart_damper, f),
}
