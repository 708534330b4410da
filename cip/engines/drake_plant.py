"""The CIP as a Drake ``MultibodyPlant``, built from the compiled MuJoCo model.

Every physical number is read from the ``mujoco.MjModel`` that
:func:`cip.model.build` compiles from :class:`cip.model.CIPParams`, so that the
Drake plant and the MuJoCo model cannot drift apart:

* cart ``cart_<i>``: a rigid body of the cart's mass M (kg) on a prismatic
  joint ``x_M<i>`` along the MJCF slide axis (+x), its rail frame at the cart's
  reference position (x = -+l/2 in the coupled model), so that the joint
  coordinate is the MJCF ``qpos`` of the slide (m);
* pendulum ``pendulum_<i>``: a revolute joint ``theta_<i>`` about the MJCF hinge
  axis (+y, so that theta > 0 tilts the tip to +x, as in MuJoCo) at the cart's
  origin; the pole is massless and the body carries the bob: mass m (bob plus
  half the rod) at the tip (0, 0, L) with the MJCF's central rotational inertia
  (2/5 m r^2 + 1e-12 kg m^2: a point mass, as MuJoCo's); Drake accepts the body
  because its rotational inertia about the hinge, m L^2, is positive;
* rod (coupled model): ``MultibodyPlant.AddDistanceConstraint`` between the two
  tips with the MJCF tendon's rest length ``tendon_length0`` (m) and infinite
  stiffness (a rigid massless rod).  Drake's discrete SAP solver, required for
  constraints, regularises a rigid constraint in its *near-rigid regime*: the
  constraint relaxes over a time scale of the order of the time step dt
  (threshold ``plant.get_sap_near_rigid_threshold()``, 1 by default), the
  analogue of MuJoCo's soft constraint (solref time constant 2 dt);
* gravity: the MJCF's gravity vector (m/s^2), g = alpha L;
* damping is *not* a Drake element: Drake's joint damping is implicit in the
  discrete step, whereas the MJCF's affine-bias actuators are explicit under
  MuJoCo's Euler.  The tip damping force -gamma m v_tip,x (N, on the absolute
  x velocity of the tip, v_tip,x = v_M + L cos(theta) theta') and the cart
  damping -gamma M v_M (N) are therefore evaluated at the state at the start of
  each step and applied with the control as generalised forces
  (:func:`generalized_forces`), exactly like MuJoCo's bias forces.

Drake's discrete step (SAP, Castro et al. 2022) is v+ = v + dt M(q)^-1 (tau(q, v)
+ J^T gamma+), q+ = q + dt v+: semi-implicit (symplectic) Euler like MuJoCo's
``Euler`` for the explicit forces, implicit only in the constraint impulses
gamma+.  Without the rod (single model) it is the same scheme as MuJoCo's.
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np

from cip.names import (
    ROD,
    cart_body,
    cart_damper,
    cart_joint,
    hinge_joint,
    motor,
    pendulum_body,
    tip_damper,
    tip_site,
)
from cipcore.params import ParameterError

_OBJ = mujoco.mjtObj


@dataclass(frozen=True)
class CIPGeometry:
    """The physical quantities of a compiled CIP model that the Drake plant needs (SI units).

    Per controller i (tuples of length C): cart mass (kg) and reference x (m),
    bob mass (kg), tip height L (m), bob central inertia (kg m^2), the damping
    coefficients c_tip = gamma m and c_cart = gamma M (N s/m), the actuator ids
    and gears of the motors u_i; and the rod length l (m, None for one
    controller, or when the MJCF's rod equality is disabled), gravity vector
    (m/s^2), time step dt (s).
    """

    n_controllers: int
    timestep: float
    gravity: tuple[float, float, float]
    cart_mass: tuple[float, ...]
    cart_x0: tuple[float, ...]
    bob_mass: tuple[float, ...]
    pendulum_length: tuple[float, ...]
    bob_inertia: tuple[tuple[float, float, float], ...]
    tip_damping: tuple[float, ...]
    cart_damping: tuple[float, ...]
    motor_id: tuple[int, ...]
    motor_gear: tuple[float, ...]
    rod_length: float | None
    qpos_x: tuple[int, ...]
    qpos_theta: tuple[int, ...]
    dof_x: tuple[int, ...]
    dof_theta: tuple[int, ...]


def _id(m: mujoco.MjModel, obj: mujoco.mjtObj, name: str) -> int:
    i = mujoco.mj_name2id(m, obj, name)
    if i < 0:
        raise ParameterError(f"the MuJoCo model has no {obj.name[6:].lower()} named {name!r}")
    return i


def geometry_from_mujoco(m: mujoco.MjModel) -> CIPGeometry:
    """Read the CIP's physical quantities from the MJCF of :func:`cip.model.mjcf`.

    Raises :class:`ParameterError` (one line) when the model is not that CIP:
    joint axes other than slide +x and hinge +y, a rotated bob inertia, or a
    damping actuator other than an affine velocity bias.
    """
    nc = 0
    while mujoco.mj_name2id(m, _OBJ.mjOBJ_JOINT, cart_joint(nc + 1)) >= 0:
        nc += 1
    if nc == 0:
        raise ParameterError(f"the MuJoCo model has no cart joint {cart_joint(1)}: not a CIP model")
    rows: dict[str, list] = {k: [] for k in CIPGeometry.__dataclass_fields__}
    for i in range(1, nc + 1):
        jx = _id(m, _OBJ.mjOBJ_JOINT, cart_joint(i))
        jt = _id(m, _OBJ.mjOBJ_JOINT, hinge_joint(i))
        if not np.array_equal(m.jnt_axis[jx], [1, 0, 0]) or not np.array_equal(
            m.jnt_axis[jt], [0, 1, 0]
        ):
            raise ParameterError("CIP joints must be a slide along +x and a hinge about +y")
        cart = _id(m, _OBJ.mjOBJ_BODY, cart_body(i))
        pend = _id(m, _OBJ.mjOBJ_BODY, pendulum_body(i))
        if np.any(m.body_pos[pend] != 0) or np.any(m.jnt_pos[[jx, jt]] != 0):
            raise ParameterError("the pendulum's hinge must sit at the cart's origin")
        if not np.array_equal(m.body_iquat[pend], [1, 0, 0, 0]):
            raise ParameterError("the bob's inertia must be given in the pendulum frame")
        tip = _id(m, _OBJ.mjOBJ_SITE, tip_site(i))
        L = float(m.site_pos[tip][2])
        if not np.allclose(m.body_ipos[pend], [0, 0, L], rtol=0, atol=1e-15):
            raise ParameterError("the bob's mass must sit at the tip site")
        dampers = []
        for name in (tip_damper(i), cart_damper(i)):
            a = _id(m, _OBJ.mjOBJ_ACTUATOR, name)
            if m.actuator_biastype[a] != mujoco.mjtBias.mjBIAS_AFFINE or m.actuator_gainprm[a][0]:
                raise ParameterError(f"actuator {name} must be an affine velocity bias")
            dampers.append(-float(m.actuator_biasprm[a][2] * m.actuator_gear[a][0] ** 2))
        u = _id(m, _OBJ.mjOBJ_ACTUATOR, motor(i))
        rows["cart_mass"].append(float(m.body_mass[cart]))
        rows["cart_x0"].append(float(m.body_pos[cart][0]))
        rows["bob_mass"].append(float(m.body_mass[pend]))
        rows["pendulum_length"].append(L)
        rows["bob_inertia"].append(tuple(float(v) for v in m.body_inertia[pend]))
        rows["tip_damping"].append(dampers[0])
        rows["cart_damping"].append(dampers[1])
        rows["motor_id"].append(u)
        rows["motor_gear"].append(float(m.actuator_gear[u][0] * m.actuator_gainprm[u][0]))
        rows["qpos_x"].append(int(m.jnt_qposadr[jx]))
        rows["qpos_theta"].append(int(m.jnt_qposadr[jt]))
        rows["dof_x"].append(int(m.jnt_dofadr[jx]))
        rows["dof_theta"].append(int(m.jnt_dofadr[jt]))
    rod = None
    equality_on = not m.opt.disableflags & int(mujoco.mjtDisableBit.mjDSBL_EQUALITY)
    if nc == 2 and equality_on and m.eq_active0[_id(m, _OBJ.mjOBJ_EQUALITY, ROD)]:
        rod = float(m.tendon_length0[_id(m, _OBJ.mjOBJ_TENDON, ROD)])
    return CIPGeometry(
        n_controllers=nc,
        timestep=float(m.opt.timestep),
        gravity=tuple(float(v) for v in m.opt.gravity),
        rod_length=rod,
        **{k: tuple(v) for k, v in rows.items() if v},
    )


@dataclass
class DrakeCIP:
    """A finalised Drake plant of the CIP and where its coordinates live.

    ``q_x``, ``q_theta`` index the plant's generalised positions, ``v_x``,
    ``v_theta`` its generalised velocities (one entry per controller).
    """

    plant: object
    geometry: CIPGeometry
    q_x: np.ndarray
    q_theta: np.ndarray
    v_x: np.ndarray
    v_theta: np.ndarray


def load_pydrake() -> None:
    """Import the pydrake modules :func:`build_plant` uses (about 0.25 s, once a process)."""
    import pydrake.math
    import pydrake.multibody.plant
    import pydrake.multibody.tree  # noqa: F401


def build_plant(g: CIPGeometry) -> DrakeCIP:
    """The discrete (time step dt, SAP) ``MultibodyPlant`` of the CIP described by ``g``."""
    from pydrake.math import RigidTransform
    from pydrake.multibody.plant import DiscreteContactApproximation, MultibodyPlant
    from pydrake.multibody.tree import (
        FixedOffsetFrame,
        PrismaticJoint,
        RevoluteJoint,
        RotationalInertia,
        SpatialInertia,
    )

    plant = MultibodyPlant(time_step=g.timestep)
    plant.set_discrete_contact_approximation(DiscreteContactApproximation.kSap)
    plant.mutable_gravity_field().set_gravity_vector(np.array(g.gravity))
    joints, pendula = [], []
    for i in range(g.n_controllers):
        M, m, L = g.cart_mass[i], g.bob_mass[i], g.pendulum_length[i]
        cart = plant.AddRigidBody(
            cart_body(i + 1),
            SpatialInertia.MakeFromCentralInertia(M, np.zeros(3), RotationalInertia(1, 1, 1) * M),
        )
        pend = plant.AddRigidBody(
            pendulum_body(i + 1),
            SpatialInertia.MakeFromCentralInertia(
                m, np.array([0.0, 0.0, L]), RotationalInertia(*g.bob_inertia[i])
            ),
        )
        rail = plant.AddFrame(
            FixedOffsetFrame(
                f"rail_{i + 1}", plant.world_frame(), RigidTransform([g.cart_x0[i], 0.0, 0.0])
            )
        )
        jx = plant.AddJoint(
            PrismaticJoint(cart_joint(i + 1), rail, cart.body_frame(), np.array([1.0, 0.0, 0.0]))
        )
        jt = plant.AddJoint(
            RevoluteJoint(
                hinge_joint(i + 1), cart.body_frame(), pend.body_frame(), np.array([0.0, 1.0, 0.0])
            )
        )
        joints.append((jx, jt))
        pendula.append(pend)
    if g.rod_length is not None:
        tips = [np.array([0.0, 0.0, g.pendulum_length[i]]) for i in range(2)]
        plant.AddDistanceConstraint(pendula[0], tips[0], pendula[1], tips[1], g.rod_length)
    plant.Finalize()
    return DrakeCIP(
        plant=plant,
        geometry=g,
        q_x=np.array([jx.position_start() for jx, _ in joints]),
        q_theta=np.array([jt.position_start() for _, jt in joints]),
        v_x=np.array([jx.velocity_start() for jx, _ in joints]),
        v_theta=np.array([jt.velocity_start() for _, jt in joints]),
    )


def generalized_forces(
    g: CIPGeometry, theta: np.ndarray, v_cart: np.ndarray, omega: np.ndarray, u: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Control plus explicit damping as generalised forces on (x_M, theta), arrays (..., C).

    The MJCF's forces at the state of the start of the step: on the cart
    u - c_cart v_M - c_tip v_tip,x (N) and on the hinge
    -c_tip v_tip,x L cos(theta) (N m), with v_tip,x = v_M + L cos(theta) theta'
    (m/s) and L cos(theta) the moment arm of the tip's x about the hinge.
    Returns (force on the cart, torque on the hinge).
    """
    L = np.asarray(g.pendulum_length)
    arm = L * np.cos(theta)
    f_tip = -np.asarray(g.tip_damping) * (v_cart + arm * omega)
    return u - np.asarray(g.cart_damping) * v_cart + f_tip, f_tip * arm
