"""The full rigid-body CIP as MJCF: physical parameters, mapping, generator.

Each balancer is a cart of mass M on a world slide joint ``x_M<i>`` carrying a
massless pole of length L on a hinge ``theta_<i>`` with a bob of mass m at its
tip (site ``tip_<i>``).  In the coupled model a rod of length l joins the two
tips: a spatial tendon ``rod`` between the tip sites held at its initial
length by a tendon equality (a massless distance constraint, no extra DOF).

How the rigid body maps onto the reduced model (checked by :mod:`cip.linearize`
and stated in the README's mapping table).  With e = L sin(theta) (bob x minus cart x) and small
angles, the bob obeys x_T'' + gamma x_T' = (g/L) e exactly, whatever the cart
does, so

* alpha = g / L                                  (L = 9.81 / 22 = 0.446 m)
* tip damping gamma: force -gamma m v_tip,x at the tip (affine-bias actuator
  with site transmission, ``refsite`` in the world)
* cart damping gamma: force -gamma M v_cart (affine-bias actuator on the slide,
  explicit under ``Euler`` like the reduced semi-implicit stepper; joint
  damping would be integrated implicitly)
* control u_i: a motor on the slide with force M * beta * R_i * e_i(t - tau)

What the rigid body adds: the cart feels the pendulum's reaction,
x_M'' + gamma x_M' = u - (m/M) alpha e, i.e. the error dynamics see
alpha_eff = alpha (1 + m/M); it vanishes as m/M -> 0.  The rod's tension
cancels out of the cart equations; the soft equality constraint acts as a stiff
spring-damper on the difference of the tip displacements.  A bob of radius r > 0
adds its rotational inertia, kappa = 2/5 (r/L)^2, which couples the tip to the
cart's acceleration (it shifts the STCC peak measurably; point mass by default:
at r = 2 cm it moved the single model's STCC peak by -2.7 ms).  A rod mass m_rod is
lumped half at each tip (exact for the translation of a rigid rod, which stays
horizontal to second order in the angles).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import mujoco

from cipcore.atomic import write_text
from cipcore.models import MODEL_NAMES, get_model
from cipcore.params import BalanceParams, ParameterError, check_choice, check_positive

INTEGRATORS = ("Euler", "implicitfast", "implicit", "RK4")
MODEL_DIR = Path(__file__).resolve().parent.parent / "models"


@dataclass(frozen=True)
class CIPParams:
    """Physical parameters of the MuJoCo CIP (SI units).

    Defaults give the paper's alpha = 22 1/s^2 and gamma = 50 1/s with
    m/M = 1e-3, so that the linearised full model matches the reduced model
    to 0.1 % (the cart reaction term, see the module docstring).
    """

    gravity: float = 9.81  # m/s^2
    pendulum_length: float = 9.81 / 22.0  # L, m
    bob_mass: float = 1e-3  # m, kg
    cart_mass: float = 1.0  # M, kg
    tip_damping: float = 50.0  # gamma of the tip, 1/s (force -gamma m v_tip)
    cart_damping: float = 50.0  # gamma of the cart, 1/s (force -gamma M v_cart)
    rod_length: float = 1.0  # l, m
    rod_mass: float = 0.0  # kg, lumped half at each tip
    bob_radius: float = 0.0  # m: physical radius, inertia 2/5 m r^2 (0: point mass)
    bob_visual_radius: float = 0.02  # m: size of the drawn sphere only (no mass, no contact)
    solref: tuple[float, float] = (0.002, 1.0)  # rod constraint time constant (s), damping ratio
    solimp: tuple[float, float, float] = (0.99, 0.99, 0.001)
    timestep: float = 1e-3  # s
    integrator: str = "Euler"

    def __post_init__(self) -> None:
        for name in (
            "gravity", "pendulum_length", "bob_mass", "cart_mass", "rod_length",
            "bob_visual_radius", "timestep",
        ):  # fmt: skip
            check_positive(name, getattr(self, name))
        for name in ("tip_damping", "cart_damping", "rod_mass", "bob_radius"):
            check_positive(name, getattr(self, name), allow_zero=True)
        check_choice("integrator", self.integrator, INTEGRATORS)
        if len(self.solref) != 2 or self.solref[0] <= 0:
            raise ParameterError(f"solref must be (timeconst > 0, dampratio), got {self.solref}")
        if len(self.solimp) != 3 or not all(0 < v < 1 for v in self.solimp[:2]):
            raise ParameterError(
                f"solimp must be (dmin, dmax, width), 0 < d < 1; got {self.solimp}"
            )

    # --- mapping -------------------------------------------------------
    @classmethod
    def from_reduced(
        cls,
        params: BalanceParams,
        *,
        gravity: float = 9.81,
        mass_ratio: float = 1e-3,
        cart_mass: float = 1.0,
        **physical,
    ) -> CIPParams:
        """A rigid body whose linearisation is the reduced model (up to m/M terms).

        L = g / alpha, tip and cart damping gamma, m = mass_ratio * M,
        timestep dt.  Extra keyword arguments set other physical parameters.
        """
        check_positive("mass_ratio", mass_ratio)
        if params.alpha <= 0:
            raise ParameterError(
                f"alpha must be > 0 for a pendulum (L = g/alpha), got {params.alpha}"
            )
        return cls(
            gravity=gravity,
            pendulum_length=gravity / params.alpha,
            bob_mass=mass_ratio * cart_mass,
            cart_mass=cart_mass,
            tip_damping=params.gamma,
            cart_damping=params.gamma,
            timestep=params.dt,
            **physical,
        )

    @property
    def tip_mass(self) -> float:
        """Mass moving with each tip: bob plus half the rod (kg)."""
        return self.bob_mass + 0.5 * self.rod_mass

    @property
    def mass_ratio(self) -> float:
        """m/M with m the tip mass: the size of the cart-reaction term."""
        return self.tip_mass / self.cart_mass

    def implied_reduced(self) -> dict[str, float]:
        """The reduced-model parameters this rigid body implies, with its extra terms.

        alpha = g/L (1/s^2); tip and cart gamma (1/s); the cart reaction
        coefficient (m/M) alpha (1/s^2); alpha_eff = alpha (1 + m/M), seen by
        the balancing error; and the rod constraint's reference stiffness and
        damping in constraint space, from MuJoCo's soft-constraint model
        a_ref = -b v - k r with b = 2 / (dmax timeconst) (1/s) and
        k = d(0) / (dmax^2 timeconst^2 dampratio^2) (1/s^2), d(0) = dmin.
        The difference of the tip displacements obeys delta'' ~ -k delta.
        """
        alpha = self.gravity / self.pendulum_length
        tc, zeta = self.solref
        dmin, dmax = self.solimp[0], self.solimp[1]
        return {
            "alpha": alpha,
            "gamma_tip": self.tip_damping,
            "gamma_cart": self.cart_damping,
            "mass_ratio": self.mass_ratio,
            "cart_reaction": self.mass_ratio * alpha,
            "alpha_eff": alpha * (1 + self.mass_ratio),
            "rod_stiffness": dmin / (dmax**2 * tc**2 * zeta**2),
            "rod_damping": 2.0 / (dmax * tc),
        }

    def with_(self, **changes) -> CIPParams:
        return replace(self, **changes)

    def as_dict(self) -> dict:
        d = asdict(self)
        d["solref"] = list(self.solref)
        d["solimp"] = list(self.solimp)
        return d


def _f(x: float) -> str:
    """Shortest round-trip text of a float (stable across platforms)."""
    return repr(float(x))


def bob_rotational_inertia(p: CIPParams) -> float:
    """Rotational inertia of the bob about its centre, 2/5 m r^2 (kg m^2).

    A point mass (r = 0) gets 1e-12 so that MuJoCo accepts the body; its
    effect, kappa = I / (m L^2) ~ 1e-9, is far below every tolerance.
    """
    return 0.4 * p.bob_mass * p.bob_radius**2 + 1e-12


def mjcf(model: str, p: CIPParams | None = None) -> str:
    """MJCF text of the single or coupled CIP for physical parameters ``p``.

    Names follow the paper: joints ``x_M<i>`` (cart) and ``theta_<i>``, sites
    ``tip_<i>`` and ``base_<i>``, motors ``u_<i>``, the tendon and equality
    ``rod``; sensors are named after the shared schema's fields.
    """
    nc = get_model(model).n_controllers
    p = p or CIPParams()
    L, m, M = p.pendulum_length, p.tip_mass, p.cart_mass
    bob_inertia = bob_rotational_inertia(p)
    xs = [0.0] if nc == 1 else [0.5 * p.rod_length, -0.5 * p.rod_length]
    span = max(3.0, p.rod_length + 2.0)
    bodies = []
    for i, x0 in enumerate(xs, start=1):
        bodies.append(f"""\
    <body name="cart_{i}" pos="{_f(x0)} 0 0">
      <joint name="x_M{i}" type="slide" axis="1 0 0"/>
      <inertial pos="0 0 0" mass="{_f(M)}" diaginertia="0.001 0.001 0.001"/>
      <geom name="cart_{i}" type="box" size="0.08 0.05 0.025" material="cart"/>
      <site name="base_{i}" pos="0 0 0" size="0.01"/>
      <body name="pendulum_{i}" pos="0 0 0">
        <joint name="theta_{i}" type="hinge" axis="0 1 0"/>
        <inertial pos="0 0 {_f(L)}" mass="{_f(m)}" diaginertia="{_f(bob_inertia)} \
{_f(bob_inertia)} {_f(bob_inertia)}"/>
        <geom name="pole_{i}" type="capsule" fromto="0 0 0 0 0 {_f(L)}" size="0.006" \
material="pole"/>
        <geom name="bob_{i}" type="sphere" pos="0 0 {_f(L)}" size="{_f(p.bob_visual_radius)}" \
material="bob"/>
        <site name="tip_{i}" pos="0 0 {_f(L)}" size="0.005"/>
      </body>
    </body>""")
    actuators, sensors = [], []
    for i in range(1, nc + 1):
        actuators.append(f'    <motor name="u_{i}" joint="x_M{i}" gear="1"/>')
    for i in range(1, nc + 1):
        actuators.append(
            f'    <general name="tip_damping_{i}" site="tip_{i}" refsite="origin" '
            f'gear="1 0 0 0 0 0" gainprm="0" biastype="affine" '
            f'biasprm="0 0 {_f(-p.tip_damping * m)}"/>'
        )
        actuators.append(
            f'    <general name="cart_damping_{i}" joint="x_M{i}" gainprm="0" '
            f'biastype="affine" biasprm="0 0 {_f(-p.cart_damping * M)}"/>'
        )
        sensors += [
            f'    <jointpos name="base_position_{i}" joint="x_M{i}"/>',
            f'    <jointvel name="base_velocity_{i}" joint="x_M{i}"/>',
            f'    <jointpos name="angle_{i}" joint="theta_{i}"/>',
            f'    <framepos name="tip_position_{i}" objtype="site" objname="tip_{i}"/>',
            f'    <framelinvel name="tip_velocity_{i}" objtype="site" objname="tip_{i}"/>',
        ]
    rod = ""
    if nc == 2:
        sensors.append('    <tendonpos name="rod_length" tendon="rod"/>')
        rod = f"""
  <tendon>
    <spatial name="rod" width="0.008" material="rod">
      <site site="tip_1"/>
      <site site="tip_2"/>
    </spatial>
  </tendon>

  <equality>
    <tendon name="rod" tendon1="rod" polycoef="0 1 0 0 0" \
solref="{_f(p.solref[0])} {_f(p.solref[1])}" \
solimp="{_f(p.solimp[0])} {_f(p.solimp[1])} {_f(p.solimp[2])}"/>
  </equality>
"""
    title = "single cart-pendulum" if nc == 1 else "coupled inverted pendula (CIP)"
    return f"""\
<!-- {title}: generated by cip.model.mjcf; edit the generator, not this file -->
<mujoco model="cip_{model}">
  <compiler angle="radian" autolimits="true"/>

  <option timestep="{_f(p.timestep)}" integrator="{p.integrator}" \
gravity="0 0 {_f(-p.gravity)}" tolerance="1e-12" iterations="50">
    <flag contact="disable"/>
  </option>

  <visual>
    <global azimuth="90" elevation="-10"/>
  </visual>

  <asset>
    <texture name="grid" type="2d" builtin="checker" rgb1=".2 .3 .4" rgb2=".1 .2 .3" \
width="300" height="300"/>
    <material name="grid" texture="grid" texrepeat="8 8" reflectance=".2"/>
    <material name="cart" rgba=".6 .6 .65 1"/>
    <material name="pole" rgba=".85 .6 .3 1"/>
    <material name="bob" rgba=".8 .2 .2 1"/>
    <material name="rod" rgba=".2 .6 .9 1"/>
    <material name="rail" rgba=".3 .3 .3 1"/>
  </asset>

  <worldbody>
    <light pos="0 -2 3" dir="0 1 -1"/>
    <geom name="floor" type="plane" pos="0 0 -0.05" size="{_f(span)} 1 0.1" material="grid"/>
    <geom name="rail" type="box" pos="0 0 -0.03" size="{_f(span)} 0.01 0.005" material="rail"/>
    <site name="origin" pos="0 0 0" size="0.005"/>
{chr(10).join(bodies)}
  </worldbody>
{rod}
  <actuator>
{chr(10).join(actuators)}
  </actuator>

  <sensor>
{chr(10).join(sensors)}
  </sensor>
</mujoco>
"""


def build(model: str, p: CIPParams | None = None) -> mujoco.MjModel:
    """Compile the MJCF of :func:`mjcf` into an ``MjModel``."""
    return mujoco.MjModel.from_xml_string(mjcf(model, p))


def write_models(directory: Path = MODEL_DIR) -> list[Path]:
    """Write ``cip_single.xml`` and ``cip_coupled.xml`` at the default parameters."""
    directory.mkdir(parents=True, exist_ok=True)
    out = []
    for model in MODEL_NAMES:
        path = directory / f"cip_{model}.xml"
        write_text(path, mjcf(model))
        out.append(path)
    return out


def small_angle_limit() -> float:
    """Documented small-angle threshold (rad): 0.0775 rad (4.4 degrees).

    Below it sin(theta) = theta to 0.1 % (theta^2 / 6 < 0.001).  The nonlinear
    terms of the error dynamics are of that relative size and are amplified by
    the near-threshold, weakly unstable dynamics; 0.1 % keeps them a factor ten
    below the 1 % trajectory tolerance of the agreement checks.
    """
    return math.sqrt(6 * 0.001)
