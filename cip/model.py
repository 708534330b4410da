"""The full rigid-body CIP as MJCF: physical parameters, mapping, the shipped files edited.

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

from cip.names import (
    ROD,
    bob_geom,
    cart_body,
    cart_damper,
    pendulum_body,
    pole_geom,
    tip_damper,
    tip_site,
)
from cipcore.atomic import write_text
from cipcore.models import MODEL_NAMES, get_model
from cipcore.params import (
    MASS_RATIO_RANGE,
    BalanceParams,
    ParameterError,
    check_choice,
    check_positive,
)

INTEGRATORS = ("Euler", "implicitfast", "implicit", "RK4")
#: MuJoCo's enum of each integrator name (``<option integrator=...>``)
INTEGRATOR_ENUMS = {
    "Euler": mujoco.mjtIntegrator.mjINT_EULER,
    "implicitfast": mujoco.mjtIntegrator.mjINT_IMPLICITFAST,
    "implicit": mujoco.mjtIntegrator.mjINT_IMPLICIT,
    "RK4": mujoco.mjtIntegrator.mjINT_RK4,
}
#: The pendulum lengths (m) the rigid body is built with: L = g/alpha from the reduced
#: model's alpha (:meth:`CIPParams.from_reduced`).  10 um to 100 km: MuJoCo refuses a
#: pendulum geom much shorter ("fromto points too close"), and the paper's is 0.45 m.
PENDULUM_LENGTH_RANGE = (1e-5, 1e5)
MODEL_DIR = Path(__file__).resolve().parent.parent / "models"


def _mujoco_warning(text: str) -> None:
    """MuJoCo's warnings (``mju_warning``: e.g. "Nan, Inf or huge value in QACC") as one
    stderr line each, instead of MuJoCo's default, which also appends them to
    ``MUJOCO_LOG.TXT`` in the working directory: a command writes nothing outside its
    ``--out``.  Installed when this module is imported (every MuJoCo model cipval
    steps is built or read here)."""
    import sys

    print(f"mujoco warning: {text.strip()}", file=sys.stderr)


mujoco.set_mju_user_warning(_mujoco_warning)


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
        m_lo, m_hi = MASS_RATIO_RANGE
        if not m_lo <= mass_ratio <= m_hi:  # NaN too
            raise ParameterError(
                f"mass_ratio must be in [{m_lo:g}, {m_hi:g}] (bob / cart), got {mass_ratio}"
            )
        lo, hi = PENDULUM_LENGTH_RANGE
        if not gravity / hi <= params.alpha <= gravity / lo:
            raise ParameterError(
                f"alpha must be in [{gravity / hi:.3g}, {gravity / lo:.3g}] 1/s^2 for the rigid "
                f"body (its pendulum length L = g/alpha in [{lo:g}, {hi:g}] m), "
                f"got {params.alpha}"
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


def bob_rotational_inertia(p: CIPParams) -> float:
    """Rotational inertia of the bob about its centre, 2/5 m r^2 (kg m^2).

    A point mass (r = 0) gets 1e-12 so that MuJoCo accepts the body; its
    effect, kappa = I / (m L^2) ~ 1e-9, is far below every tolerance.
    """
    return 0.4 * p.bob_mass * p.bob_radius**2 + 1e-12


def shipped_file(model: str) -> Path:
    """The shipped MJCF ``models/cip_<model>.xml``: the CIP at the default :class:`CIPParams`."""
    return MODEL_DIR / f"cip_{get_model(model).name}.xml"


def model_spec(model: str, p: CIPParams | None = None) -> mujoco.MjSpec:
    """The shipped model file of ``model`` edited to physical parameters ``p`` (``mujoco.MjSpec``).

    The file (:func:`shipped_file`) holds the structure: bodies, joints, sites,
    actuators, sensors, rod and looks; names follow the paper (:mod:`cip.names`):
    joints ``x_M<i>`` (cart) and ``theta_<i>``, sites ``tip_<i>`` and
    ``base_<i>``, motors ``u_<i>``, the tendon and equality ``rod``; sensors are
    named after the shared schema's fields.  Set here from ``p``: time step,
    integrator and gravity; the cart positions (the rod length l apart) and
    masses M; the pendulum's inertial (bob mass m at L, rotational inertia
    :func:`bob_rotational_inertia`); the pole (capsule from the hinge to L), the
    drawn bob and the tip site at L; the damping actuators' bias -gamma m and
    -gamma M (N s/m); the rod's solref and solimp; the floor's half-length.
    Compiling the result equals compiling the former generated text of the same
    parameters field for field (every ``MjModel`` array and option, checked for
    non-default parameters and all four integrators).
    """
    nc = get_model(model).n_controllers
    p = p or CIPParams()
    spec = mujoco.MjSpec.from_file(str(shipped_file(model)))
    L, m, M = p.pendulum_length, p.tip_mass, p.cart_mass
    inertia = bob_rotational_inertia(p)
    spec.option.timestep = p.timestep
    spec.option.integrator = INTEGRATOR_ENUMS[p.integrator]
    spec.option.gravity = [0.0, 0.0, -p.gravity]
    span = max(3.0, p.rod_length + 2.0)
    for name in ("floor", "rail"):
        spec.geom(name).size[0] = span
    xs = [0.0] if nc == 1 else [0.5 * p.rod_length, -0.5 * p.rod_length]
    for i, x0 in enumerate(xs, start=1):
        cart = spec.body(cart_body(i))
        cart.pos = [x0, 0.0, 0.0]
        cart.mass = M
        pendulum = spec.body(pendulum_body(i))
        pendulum.ipos = [0.0, 0.0, L]
        pendulum.mass = m
        pendulum.inertia = [inertia, inertia, inertia]
        spec.geom(pole_geom(i)).fromto = [0.0, 0.0, 0.0, 0.0, 0.0, L]
        bob = spec.geom(bob_geom(i))
        bob.pos = [0.0, 0.0, L]
        bob.size[0] = p.bob_visual_radius
        spec.site(tip_site(i)).pos = [0.0, 0.0, L]
        spec.actuator(tip_damper(i)).biasprm[2] = -p.tip_damping * m
        spec.actuator(cart_damper(i)).biasprm[2] = -p.cart_damping * M
    if nc == 2:
        rod = spec.equality(ROD)
        rod.solref = list(p.solref)
        rod.solimp[:3] = p.solimp
    return spec


def mjcf(model: str, p: CIPParams | None = None) -> str:
    """MJCF text of the single or coupled CIP for physical parameters ``p``.

    At the default parameters (``p`` None or ``CIPParams()``) the shipped file
    verbatim.  Otherwise MuJoCo's XML of :func:`model_spec`
    (``MjSpec.to_xml``), which writes numbers to 6 significant digits
    (MuJoCo 4.0): it compiles to a model that differs from :func:`build`'s in
    the rounded parameters, so simulate with :func:`build` and read the text
    only.
    """
    if p is None or p == CIPParams():
        return shipped_file(model).read_text()
    return model_spec(model, p).to_xml()


def build(model: str, p: CIPParams | None = None) -> mujoco.MjModel:
    """Compile the CIP of :func:`model_spec` into an ``MjModel``."""
    return model_spec(model, p).compile()


def write_models(directory: Path = MODEL_DIR) -> list[Path]:
    """Copy ``cip_single.xml`` and ``cip_coupled.xml`` (the shipped files) into ``directory``."""
    directory.mkdir(parents=True, exist_ok=True)
    out = []
    for model in MODEL_NAMES:
        path = directory / f"cip_{model}.xml"
        if path.resolve() != shipped_file(model).resolve():
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
