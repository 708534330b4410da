"""Read a CIP model file: the mapping to the reduced model and the twin's terms.

A user's MJCF is validated by name (the names :func:`cip.model.mjcf` writes):

* joints ``x_M<i>`` (slide, the cart) and ``theta_<i>`` (hinge, the pendulum),
  i = 1 (single) or 1, 2 (coupled);
* sites ``tip_<i>`` (the bob) on the pendulum body;
* motors ``u_<i>`` on the cart joints (the control force F_i = M u_i);
* affine-bias actuators ``tip_damping_<i>`` (force -gamma_t m v_tip, biasprm[2] =
  -gamma_t m) and ``cart_damping_<i>`` (biasprm[2] = -gamma_c M);
* coupled: a tendon ``rod`` between the tips held by a tendon equality ``rod``
  (solref, solimp).

Read from the compiled model (:mod:`cip.conformance`: subtree masses and
``mj_fullM``, whatever frames and inertia forms the file uses): the pendulum
length L (tip site from the hinge), the masses M (cart subtree less the
pendulum's) and m (pendulum subtree), the bob's rotational inertia about its
centre of mass, gravity, the time step and the integrator, the
dampings and the rod's soft-constraint constants (MuJoCo's formulas, see
:mod:`reduced.twin`).  Anything missing or outside what the mapping covers ends
in a one-line :class:`ParameterError` naming it.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from pathlib import Path

import mujoco
import numpy as np

from cip.conformance import physical_content
from cip.model import MODEL_DIR, CIPParams
from cip.names import ROD, cart_damper, cart_joint, hinge_joint, motor, tip_damper, tip_site
from cipcore.params import ParameterError

#: Which model a file describes follows from how many balancers it has.
MODEL_BY_CONTROLLERS = {1: "single", 2: "coupled"}
#: MuJoCo's integrator enum names as the MJCF spells them (:data:`cip.model.INTEGRATORS`).
INTEGRATOR_NAMES = {
    "mjINT_EULER": "Euler",
    "mjINT_RK4": "RK4",
    "mjINT_IMPLICIT": "implicit",
    "mjINT_IMPLICITFAST": "implicitfast",
}


def shipped_model_path(model: str) -> Path:
    """The shipped model file ``models/cip_<model>.xml`` (what the default run reads)."""
    return MODEL_DIR / f"cip_{model}.xml"


def load_model_file(path: str | Path) -> mujoco.MjModel:
    """Compile an MJCF file; a one-line error if it is missing or does not compile."""
    p = Path(path)
    if p.is_dir():
        raise ParameterError(f"--mjcf: {str(path)!r} is a directory, expected an MJCF (.xml) file")
    if not p.is_file():
        raise ParameterError(f"--mjcf: no such file {str(path)!r}")
    try:
        return mujoco.MjModel.from_xml_path(str(p))
    except ValueError as exc:
        # MuJoCo's message is "XML parse error N:" then the details on the next lines
        lines = [ln.strip().rstrip(":") for ln in str(exc).strip().splitlines() if ln.strip()]
        why = ": ".join(lines)
        raise ParameterError(
            f"--mjcf: {str(path)!r} does not compile: {why or 'compile error'}"
        ) from None


@dataclass(frozen=True)
class ModelMapping:
    """What a CIP model file declares, in the reduced model's terms (SI units)."""

    model: str
    n_controllers: int
    gravity: float  # m/s^2
    pendulum_length: float  # L, m
    cart_mass: float  # M, kg
    tip_mass: float  # m, kg
    bob_inertia: float  # kg m^2 about the hinge axis through the bob
    tip_damping: float  # gamma_t, 1/s
    cart_damping: float  # gamma_c, 1/s
    timestep: float  # s
    integrator: str
    solref: tuple[float, float] | None
    solimp: tuple[float, float, float] | None
    rod_invweight0: float | None  # 1/kg

    @property
    def alpha(self) -> float:
        """g / L (1/s^2)."""
        return self.gravity / self.pendulum_length

    @property
    def mass_ratio(self) -> float:
        return self.tip_mass / self.cart_mass

    @property
    def kappa(self) -> float:
        return self.bob_inertia / (self.tip_mass * self.pendulum_length**2)

    def rod_constants(self) -> dict[str, float] | None:
        """MuJoCo's soft-constraint constants of the rod (module :mod:`reduced.twin`).

        timeconst tc = max(solref[0], 2 dt) (MuJoCo's ``refsafe``), impedance d = dmin
        at zero violation; stiffness k d = d / (dmax^2 tc^2 zeta^2) (1/s^2), damping
        b = 2 / (dmax tc) (1/s), regulariser R = (1 - d) / d * invweight0 (1/kg).
        """
        if self.solref is None or self.solimp is None or self.rod_invweight0 is None:
            return None
        tc, zeta = max(self.solref[0], 2.0 * self.timestep), self.solref[1]
        dmin, dmax = self.solimp[0], self.solimp[1]
        return {
            "timeconst": tc,
            "stiffness": dmin / (dmax**2 * tc**2 * zeta**2),
            "damping": 2.0 / (dmax * tc),
            "regulariser": (1.0 - dmin) / dmin * self.rod_invweight0,
        }

    def twin_terms(self) -> dict:
        """Keyword arguments of :class:`reduced.twin.TwinParams`."""
        rod = self.rod_constants()
        out = {
            "alpha": self.alpha,
            "gamma_tip": self.tip_damping,
            "gamma_cart": self.cart_damping,
            "mass_ratio": self.mass_ratio,
            "kappa": self.kappa,
            "dt": self.timestep,
        }
        if rod is not None:
            out.update(
                rod=True,
                rod_stiffness=rod["stiffness"],
                rod_damping=rod["damping"],
                rod_regulariser=rod["regulariser"] * self.cart_mass,
            )
        return out

    def physical(self, rod_length: float = 1.0) -> CIPParams:
        """The :class:`CIPParams` of this file (what the runner needs: L, M, dt, ...)."""
        radius = np.sqrt(max(self.bob_inertia - 1e-12, 0.0) / (0.4 * self.tip_mass))
        return CIPParams(
            gravity=self.gravity, pendulum_length=self.pendulum_length, bob_mass=self.tip_mass,
            cart_mass=self.cart_mass, tip_damping=self.tip_damping,
            cart_damping=self.cart_damping, rod_length=rod_length, bob_radius=float(radius),
            solref=self.solref or (0.002, 1.0), solimp=self.solimp or (0.99, 0.99, 0.001),
            timestep=self.timestep, integrator=self.integrator,
        )  # fmt: skip

    def as_dict(self) -> dict:
        d = asdict(self)
        d.update(alpha=self.alpha, mass_ratio=self.mass_ratio, kappa=self.kappa)
        d["rod"] = self.rod_constants()
        return d


def _id(m: mujoco.MjModel, kind: mujoco.mjtObj, name: str, what: str) -> int:
    i = mujoco.mj_name2id(m, kind, name)
    if i < 0:
        raise ParameterError(
            f"model file has no {what} {name!r} (the CIP mapping needs joints "
            f"{cart_joint('<i>')}, {hinge_joint('<i>')}, sites {tip_site('<i>')}, motors "
            f"{motor('<i>')}, actuators {tip_damper('<i>')}, {cart_damper('<i>')}, and for "
            f"two balancers a tendon and equality {ROD!r})"
        )
    return i


def _same(name: str, values: list[float]) -> float:
    if not np.allclose(values, values[0], rtol=1e-12, atol=0.0):
        raise ParameterError(f"model file: {name} differs between the balancers: {values}")
    return float(values[0])


def read_mapping(m: mujoco.MjModel) -> ModelMapping:
    """The mapping of a compiled CIP model (module docstring)."""
    J, S, A = mujoco.mjtObj.mjOBJ_JOINT, mujoco.mjtObj.mjOBJ_SITE, mujoco.mjtObj.mjOBJ_ACTUATOR
    nc = 2 if mujoco.mj_name2id(m, J, hinge_joint(2)) >= 0 else 1
    lengths, carts, tips, inertias, g_tip, g_cart = [], [], [], [], [], []
    content = None
    for i in range(1, nc + 1):
        jx = _id(m, J, cart_joint(i), "joint")
        jt = _id(m, J, hinge_joint(i), "joint")
        _id(m, S, tip_site(i), "site")
        _id(m, A, motor(i), "actuator")
        if m.jnt_type[jx] != mujoco.mjtJoint.mjJNT_SLIDE:
            raise ParameterError(f"model file: joint {cart_joint(i)} must be a slide joint")
        if m.jnt_type[jt] != mujoco.mjtJoint.mjJNT_HINGE:
            raise ParameterError(f"model file: joint {hinge_joint(i)} must be a hinge joint")
        # read from the compiled model (subtree masses, mj_fullM), so that a bob in a
        # welded child body, split frames or fullinertia read as what they are
        content = content or physical_content(m, nc)
        b = content.balancers[i - 1]
        if not b.site_in_pendulum:
            raise ParameterError(
                f"model file: site {tip_site(i)} must be on the pendulum of {hinge_joint(i)}"
            )
        lengths.append(b.pendulum_length)
        carts.append(b.cart_mass)
        tips.append(b.tip_mass)
        inertias.append(b.bob_inertia)
        at = _id(m, A, tip_damper(i), "actuator")
        ac = _id(m, A, cart_damper(i), "actuator")
        for a, nm in ((at, tip_damper(i)), (ac, cart_damper(i))):
            if m.actuator_biastype[a] != mujoco.mjtBias.mjBIAS_AFFINE or m.actuator_gainprm[a][0]:
                raise ParameterError(f"model file: actuator {nm} must be affine-bias, gain 0")
        g_tip.append(-float(m.actuator_biasprm[at][2]) / tips[-1])
        g_cart.append(-float(m.actuator_biasprm[ac][2]) / carts[-1])
    grav = m.opt.gravity
    if abs(grav[0]) > 0 or abs(grav[1]) > 0 or grav[2] >= 0:
        raise ParameterError(f"model file: gravity must point along -z, got {list(grav)}")
    solref = solimp = invw = None
    if nc == 2:
        ten = _id(m, mujoco.mjtObj.mjOBJ_TENDON, ROD, "tendon")
        eq = _id(m, mujoco.mjtObj.mjOBJ_EQUALITY, ROD, "equality")
        solref = (float(m.eq_solref[eq][0]), float(m.eq_solref[eq][1]))
        solimp = tuple(float(v) for v in m.eq_solimp[eq][:3])
        invw = float(m.tendon_invweight0[ten])
    return ModelMapping(
        model=MODEL_BY_CONTROLLERS[nc],
        n_controllers=nc,
        gravity=float(-grav[2]),
        pendulum_length=_same("pendulum length", lengths),
        cart_mass=_same("cart mass", carts),
        tip_mass=_same("tip mass", tips),
        bob_inertia=_same("bob inertia", inertias),
        tip_damping=_same("tip damping", g_tip),
        cart_damping=_same("cart damping", g_cart),
        timestep=float(m.opt.timestep),
        integrator=INTEGRATOR_NAMES[mujoco.mjtIntegrator(m.opt.integrator).name],
        solref=solref,
        solimp=solimp,
        rod_invweight0=invw,
    )


def model_files(paths: list[str] | None, dt: float = 1e-3) -> dict[str, str]:
    """``--mjcf`` paths by the model each describes; one-line errors before any run.

    ``dt`` is the controller's time step: a model stepping at another one is
    refused here (the controller's delay tau/dt would not be the engine's).
    """
    out: dict[str, str] = {}
    for path in paths or []:
        try:
            mp = read_mapping(load_model_file(path))
        except ParameterError as exc:
            if str(exc).startswith("--mjcf"):
                raise
            raise ParameterError(f"--mjcf: {str(path)!r}: {exc}") from None
        if abs(mp.timestep - dt) > 1e-12 * dt:
            raise ParameterError(
                f"--mjcf: {str(path)!r} steps at timestep {mp.timestep:g} s, the controller "
                f'assumes dt = {dt:g} s (set <option timestep="{dt:g}"/>)'
            )
        if mp.model in out:
            raise ParameterError(f"--mjcf: two files describe the {mp.model} model")
        out[mp.model] = str(path)
    return out
