"""The physical content of a compiled CIP model, read the way MuJoCo computes it.

What a model file *means* physically does not depend on how it is written: the
bob's mass may sit in the pendulum body or in a child body welded to it (no
joint between them), a body may be split into several frames, and an inertia
may be given as ``diaginertia``, ``fullinertia`` or from geoms.  Everything
here is therefore read from the compiled model after :func:`mujoco.mj_forward`
at ``qpos0`` (upright, carts at rest), never from XML attributes:

* tip mass m: the subtree mass of the pendulum body (kg);
* cart mass M: the subtree mass of the cart body minus its pendulum's (kg);
* pendulum length L: the distance from the hinge anchor to site ``tip_<i>`` (m);
* centre-of-mass offset: the pendulum subtree's centre of mass minus the tip
  site (m; zero for a bob at the tip);
* bob inertia about the axis parallel to the hinge through the subtree's
  centre of mass: every subtree body's inertia rotated to the world frame plus
  its mass at its distance from that axis (kg m^2); the inertia about the
  hinge itself is ``M[theta, theta]`` of :func:`mujoco.mj_fullM` less the
  armature (= bob inertia + m r_perp^2, r_perp the centre of mass's distance
  from the hinge axis);
* every joint property the reduced model does not have (limits, friction loss,
  armature, damping, stiffness, springref), the actuators' dynamics and gears,
  contacts, fluid forces, gravity compensation, further equalities.

:func:`physical_content` returns it as plain numbers; the specification that
judges them is :mod:`validation.checks.conformance`.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import mujoco
import numpy as np

from cip.names import ROD, cart_joint, hinge_joint, tip_site

J, S, A, B = (
    mujoco.mjtObj.mjOBJ_JOINT,
    mujoco.mjtObj.mjOBJ_SITE,
    mujoco.mjtObj.mjOBJ_ACTUATOR,
    mujoco.mjtObj.mjOBJ_BODY,
)


@dataclass(frozen=True)
class Balancer:
    """One cart-pendulum of a compiled model (SI units, module docstring)."""

    index: int
    cart_mass: float  # kg
    tip_mass: float  # kg
    pendulum_length: float  # m, hinge anchor to site tip_<i>
    com_offset: float  # m, |subtree centre of mass - tip site|
    com_arm: float  # m, centre of mass's distance from the hinge axis
    hinge_inertia: float  # kg m^2, about the hinge axis (armature excluded)
    bob_inertia: float  # kg m^2, about the parallel axis through the centre of mass
    site_in_pendulum: bool  # the tip site lies in the pendulum's subtree


@dataclass
class Content:
    """The physical content of a compiled CIP model (module docstring)."""

    balancers: list[Balancer]
    gravity: tuple[float, float, float]
    timestep: float
    integrator: str
    joints: dict[str, dict[str, float]] = field(default_factory=dict)
    actuators: dict[str, dict[str, float]] = field(default_factory=dict)
    contact_possible: bool = False
    contact_pairs: int = 0
    fluid: dict[str, float] = field(default_factory=dict)
    gravcomp: float = 0.0
    other_equalities: list[str] = field(default_factory=list)
    rod: dict[str, float] | None = None


def _descends(m: mujoco.MjModel, body: int, ancestor: int) -> bool:
    while body > 0:
        if body == ancestor:
            return True
        body = int(m.body_parentid[body])
    return ancestor == 0


def _balancer(m: mujoco.MjModel, d: mujoco.MjData, qm: np.ndarray, i: int) -> Balancer:
    jx = mujoco.mj_name2id(m, J, cart_joint(i))
    jt = mujoco.mj_name2id(m, J, hinge_joint(i))
    site = mujoco.mj_name2id(m, S, tip_site(i))
    pend, cart = int(m.jnt_bodyid[jt]), int(m.jnt_bodyid[jx])
    mass = float(m.body_subtreemass[pend])
    anchor, axis = d.xanchor[jt], d.xaxis[jt] / np.linalg.norm(d.xaxis[jt])
    arm = d.subtree_com[pend] - anchor
    r_perp = float(np.linalg.norm(arm - np.dot(arm, axis) * axis))
    dof = int(m.jnt_dofadr[jt])
    hinge = float(qm[dof, dof] - m.dof_armature[dof])
    # composite inertia about the axis through the subtree's centre of mass: each body's
    # own inertia (rotated to the world) plus its mass at its distance from that axis
    bob, cart_mass = 0.0, 0.0
    for b in range(1, m.nbody):
        if _descends(m, b, pend):
            rot = d.ximat[b].reshape(3, 3) @ axis
            bob += float(np.dot(rot**2, m.body_inertia[b]))
            off = d.xipos[b] - d.subtree_com[pend]
            off = off - np.dot(off, axis) * axis
            bob += float(m.body_mass[b] * np.dot(off, off))
        elif _descends(m, b, cart):
            cart_mass += float(m.body_mass[b])
    return Balancer(
        index=i,
        cart_mass=cart_mass,
        tip_mass=mass,
        pendulum_length=float(np.linalg.norm(d.site_xpos[site] - anchor)),
        com_offset=float(np.linalg.norm(d.subtree_com[pend] - d.site_xpos[site])),
        com_arm=r_perp,
        hinge_inertia=hinge,
        bob_inertia=bob,
        site_in_pendulum=_descends(m, int(m.site_bodyid[site]), pend),
    )


def _name(m: mujoco.MjModel, kind: mujoco.mjtObj, i: int) -> str:
    return mujoco.mj_id2name(m, kind, i) or f"#{i}"


def _contact_possible(m: mujoco.MjModel) -> bool:
    """Could any two geoms of different bodies collide (contype/conaffinity filter)?"""
    if m.opt.disableflags & int(mujoco.mjtDisableBit.mjDSBL_CONTACT):
        return False
    for a in range(m.ngeom):
        for b in range(a + 1, m.ngeom):
            if m.geom_bodyid[a] == m.geom_bodyid[b]:
                continue
            if (m.geom_contype[a] & m.geom_conaffinity[b]) or (
                m.geom_contype[b] & m.geom_conaffinity[a]
            ):
                return True
    return False


def physical_content(m: mujoco.MjModel, n_controllers: int) -> Content:
    """Read the physical content of a compiled CIP model (module docstring).

    ``n_controllers`` is 1 or 2; the names ``x_M<i>``, ``theta_<i>``, ``tip_<i>``
    must exist (:func:`cip.mjcf_params.read_mapping` checks them first).
    """
    d = mujoco.MjData(m)
    mujoco.mj_forward(m, d)
    qm = np.zeros((m.nv, m.nv))
    mujoco.mj_fullM(m, d, qm)
    balancers = [_balancer(m, d, qm, i) for i in range(1, n_controllers + 1)]
    joints = {}
    for j in range(m.njnt):
        dof = int(m.jnt_dofadr[j])
        joints[_name(m, J, j)] = {
            "type": int(m.jnt_type[j]),
            "limited": bool(m.jnt_limited[j]),
            "range_low": float(m.jnt_range[j][0]),
            "range_high": float(m.jnt_range[j][1]),
            "frictionloss": float(m.dof_frictionloss[dof]),
            "armature": float(m.dof_armature[dof]),
            "damping": float(m.dof_damping[dof]),
            "stiffness": float(m.jnt_stiffness[j]),
            "actfrclimited": bool(m.jnt_actfrclimited[j]),
        }
    actuators = {}
    for a in range(m.nu):
        actuators[_name(m, A, a)] = {
            "dyntype": int(m.actuator_dyntype[a]),
            "gear": [float(g) for g in m.actuator_gear[a]],
            "ctrllimited": bool(m.actuator_ctrllimited[a]),
            "forcelimited": bool(m.actuator_forcelimited[a]),
            "actlimited": bool(m.actuator_actlimited[a]),
        }
    others = []
    rod = None
    eq_rod = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_EQUALITY, ROD)
    for e in range(m.neq):
        if e == eq_rod:
            continue
        active = bool(m.eq_active0[e]) and not (
            m.opt.disableflags & int(mujoco.mjtDisableBit.mjDSBL_EQUALITY)
        )
        if active:
            others.append(_name(m, mujoco.mjtObj.mjOBJ_EQUALITY, e))
    ten = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_TENDON, ROD)
    if ten >= 0:
        rod = {
            "stiffness": float(np.max(np.abs(m.tendon_stiffness[ten]))),
            "damping": float(np.max(np.abs(m.tendon_damping[ten]))),
            "frictionloss": float(m.tendon_frictionloss[ten]),
            "limited": bool(m.tendon_limited[ten]),
            "equality_active": bool(eq_rod >= 0 and m.eq_active0[eq_rod])
            and not (m.opt.disableflags & int(mujoco.mjtDisableBit.mjDSBL_EQUALITY)),
        }
    return Content(
        balancers=balancers,
        gravity=tuple(float(g) for g in m.opt.gravity),
        timestep=float(m.opt.timestep),
        integrator=mujoco.mjtIntegrator(m.opt.integrator).name,
        joints=joints,
        actuators=actuators,
        contact_possible=_contact_possible(m),
        contact_pairs=int(m.npair)
        if not (m.opt.disableflags & int(mujoco.mjtDisableBit.mjDSBL_CONTACT))
        else 0,
        fluid={
            "density": float(m.opt.density),
            "viscosity": float(m.opt.viscosity),
            "wind": float(np.max(np.abs(m.opt.wind))),
        },
        gravcomp=float(np.max(np.abs(m.body_gravcomp))) if m.nbody else 0.0,
        other_equalities=others,
        rod=rod,
    )
