"""The exact linear twin of the rigid-body CIP: an instrument, not the paper's model.

The paper's reduced model (eqs. (3), (5)) is the scientific
reference.  The rigid body differs from it by small, known terms; the twin is the
reduced model extended by exactly those terms, linearised about upright and
stepped the way MuJoCo's ``Euler`` integrator steps, so that at small amplitude
the full model and its twin agree to the engine's own precision and any fault
that moves the physics stands out far above that floor.

Per balancer i, in the generalised coordinates of the MJCF, the cart position
x_i and the balancing error e_i = L theta_i (m), per unit cart mass M
(mu = m/M the tip-to-cart mass ratio, kappa = I_bob / (m L^2)), the Lagrange
equations of a cart with a pendulum whose mass m sits at the tip are::

    (1 + mu) x_i'' + mu e_i''             = u_i - gamma_c x_i' - gamma_t mu v_Ti + s_i f
    mu x_i''       + mu (1 + kappa) e_i'' = mu alpha e_i      - gamma_t mu v_Ti + s_i f

with alpha = g/L, v_Ti = x_i' + e_i' the tip velocity, u_i = beta R_i(t)
e_i(t - tau) the control (paper eq. (5)), gamma_t the tip damping (a force
-gamma_t m v_T at the tip) and gamma_c the cart damping.  Eliminating x_i'' gives
the reduced model's tip equation x_Ti'' + gamma_t x_Ti' = alpha e_i - kappa e_i''
and the cart equation x_i'' + gamma_c x_i' = u_i - mu alpha e_i + mu kappa e_i'':
the cart reaction -(m/M) alpha e (alpha_eff = alpha (1 + m/M) for the balancing
error) and the bob's rotational inertia kappa are the known extra terms.

Coupled model (C = 2): the rod is MuJoCo's soft equality constraint on the tip
separation delta = (x_1 + e_1) - (x_2 + e_2), Jacobian J = (+1, +1, -1, -1) in
(x_1, e_1, x_2, e_2).  Its force per unit M, s_1 = +1, s_2 = -1, is MuJoCo's
soft-constraint solution for one equality row,

    f = (a_ref - J a_0) / (A + R),     a_ref = -b delta' - k d delta,

with a_0 the unconstrained accelerations, A = J M^-1 J^T, b = 2 / (dmax tc),
k = 1 / (dmax^2 tc^2 zeta^2), d = dmin the impedance at zero violation,
R = (1 - d)/d * A_0 the regulariser (A_0 = MuJoCo's ``tendon_invweight0``) and
tc = max(solref timeconst, 2 dt) (MuJoCo's ``refsafe`` clamp).

Step: the engine's integrator (``TwinParams.integrator``, MuJoCo's names), as
MuJoCo defines it: ``Euler``: a = M^-1 (forces) at the current state, v <- v +
dt a, q <- q + dt v (semi-implicit; the damping is explicit because the MJCF
applies it with affine-bias actuators, not joint damping); ``implicit`` and
``implicitfast``: the same with a = (M - dt D)^-1 (forces), D the dampers'
velocity derivative (the rod's force still from the explicit M); ``RK4``: the
classical Runge-Kutta method, control held over the step (see
:mod:`reduced._twin_kernel`); and two engines' own steppers with the rod rigid
(:mod:`reduced._twin_schemes`): ``Newmark`` (beta = 1/2, gamma = 1, the rod an
index-3 constraint, Exudyn) and ``RK-Merson`` (fixed step, the rod's force from
J a = 0, Simbody), both with the control and the dampers held over the step.
A rigid rod (Drake's distance constraint in SAP's near-rigid regime) is the same
one-row solution with k = 1/dt^2, b = 1/dt and R = A beta_nr^2 / (4 pi^2)
(Castro et al. 2022): the engine declares its rod's constants
(``rod_stiffness``, ``rod_damping``, ``rod_regulariser``). What the twin does
not capture are terms of second order in the angles (sin theta - theta, the
pendulum's cos theta in the mass matrix and the moment arms, the rod's tilt when
the tips are at unequal heights): relative size theta^2, below 1e-10 at the
amplitudes where the twin is used (1e-6 m, theta ~ 2e-6 rad).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, replace

import numpy as np

from cipcore.noise import GainNoise
from cipcore.params import BalanceParams, ParameterError, check_positive
from cipcore.scenario import Execution, Recording, Scenario
from cipcore.schema import Trajectory

from ._twin_kernel import KERNELS
from .simulate import n_controllers, plan_run

#: MuJoCo's integrator names -> the kernel's scheme (:func:`reduced._twin_kernel._advance`);
#: "Newmark" (beta 1/2, gamma 1) and "RK-Merson" (fixed step) hold the rod rigid.
TWIN_SCHEMES = {"Euler": 0, "implicit": 1, "implicitfast": 1, "RK4": 2, "Newmark": 3,
                "RK-Merson": 4}  # fmt: skip


@dataclass(frozen=True)
class TwinParams:
    """The rigid body's linear terms (SI units; forces per unit cart mass).

    alpha : g / L (1/s^2).  gamma_tip, gamma_cart : damping (1/s).
    mass_ratio : mu = m / M, m the mass moving with the tip.
    kappa : I_bob / (m L^2), the bob's rotational inertia.
    dt : the engine's time step (s), read from the model.
    rod : whether a rod joins the tips (coupled model).
    rod_stiffness : k d (1/s^2), rod_damping : b (1/s), rod_regulariser :
        R per unit M (MuJoCo's (1 - d)/d * tendon_invweight0 * M).
    integrator : the engine's stepper in MuJoCo's names: "Euler", "implicit",
        "implicitfast" or "RK4".
    """

    alpha: float
    gamma_tip: float
    gamma_cart: float
    mass_ratio: float
    kappa: float
    dt: float
    rod: bool = False
    rod_stiffness: float = 0.0
    rod_damping: float = 0.0
    rod_regulariser: float = 0.0
    integrator: str = "Euler"

    def __post_init__(self) -> None:
        if self.integrator not in TWIN_SCHEMES:
            raise ParameterError(
                f"integrator must be one of {', '.join(TWIN_SCHEMES)}, got {self.integrator!r}"
            )
        check_positive("mass_ratio", self.mass_ratio)
        check_positive("dt", self.dt)
        check_positive("kappa", self.kappa, allow_zero=True)

    def inverse_mass(self) -> np.ndarray:
        """Inverse of the per-unit-M mass matrix [[1 + mu, mu], [mu, mu (1 + kappa)]] in (x, e)."""
        mu, kappa = self.mass_ratio, self.kappa
        return np.linalg.inv(np.array([[1.0 + mu, mu], [mu, mu * (1.0 + kappa)]]))

    def step_matrix(self) -> np.ndarray:
        """The matrix one step applies to the forces: M^-1, or (M - dt D)^-1 for the
        implicit integrators (D the dampers' velocity derivative, per unit M), or
        (M - (h^2/2) K)^-1 for Newmark (K q = (0, mu alpha e), gravity at q+)."""
        mu, kappa, h = self.mass_ratio, self.kappa, self.dt
        if TWIN_SCHEMES[self.integrator] == 3:
            k = np.array([[0.0, 0.0], [0.0, mu * self.alpha]])
            m = np.array([[1.0 + mu, mu], [mu, mu * (1.0 + kappa)]])
            return np.linalg.inv(m - 0.5 * h * h * k)
        if TWIN_SCHEMES[self.integrator] != 1:
            return self.inverse_mass()
        gt, gc = self.gamma_tip * mu, self.gamma_cart
        m = np.array([[1.0 + mu, mu], [mu, mu * (1.0 + kappa)]])
        return np.linalg.inv(m + h * np.array([[gc + gt, gt], [gt, gt]]))

    def rod_mobility(self) -> float:
        """A = J M^-1 J^T per unit M (dimensionless): the rod's inverse effective mass."""
        mi = self.inverse_mass()
        return 2.0 * float(mi.sum())

    def as_dict(self) -> dict:
        return asdict(self)


def twin_coefficients(twin: TwinParams, params: BalanceParams) -> np.ndarray:
    """The kernel's ``coef`` (:func:`reduced._twin_kernel._advance`) for ``twin``
    under the controller of ``params`` (beta in 1/s^2, the noise scale nu / sqrt(dt))."""
    return np.array([
        twin.alpha, twin.gamma_tip, twin.gamma_cart, twin.mass_ratio, params.beta,
        params.noise_scale, twin.dt, 1.0 if twin.rod else 0.0, twin.rod_stiffness,
        twin.rod_damping, twin.rod_mobility(), twin.rod_regulariser,
    ])  # fmt: skip


def simulate_twin(
    scenario: Scenario,
    twin: TwinParams,
    *,
    noise: GainNoise | None = None,
    recording: Recording = Recording(),
    execution: Execution = Execution(),
) -> Trajectory:
    """Time series of the twin, same call and schema as :func:`reduced.simulate.simulate`.

    The scenario's ``params`` give the controller (beta, nu, tau and the dt it
    assumes, so d = tau/dt and the noise scale nu/sqrt(dt)); ``twin`` the body,
    stepped at ``twin.dt``.  Initial condition as the MuJoCo runs: at rest, every
    balancing error at the scenario's ``amplitude`` with the constant history
    e(t) = amplitude, t < 0.  The twin records float64 (``recording.dtype`` is not
    used) and shows no progress bar.
    """
    params = scenario.params
    nc = n_controllers(scenario.model)
    if twin.rod and nc != 2:
        raise ParameterError(f"a rod needs the coupled model, got model {scenario.model!r}")
    run = plan_run(scenario, replace(recording, dtype=np.float64), noise, twin.dt)
    nreal, d = run.noise.n_realizations, params.delay_steps
    state = np.zeros((nreal, nc, 4))
    state[:, :, 1] = run.amplitude
    hist = np.full((nreal, nc, d), run.amplitude)
    coef = twin_coefficients(twin, params)
    minv = twin.inverse_mass()
    mstep = twin.step_matrix()
    advance_twin = KERNELS[TWIN_SCHEMES[twin.integrator]][0]

    def advance(block: slice, xi: np.ndarray, n0: int, nrec: int) -> np.ndarray:
        rec = np.empty((xi.shape[0], nrec, nc, 4))
        advance_twin(
            xi, state[block], hist[block], n0 % d, coef, minv, mstep, n0, run.decimate, rec
        )
        return rec

    run.run(advance, threads=execution.threads)
    attrs = run.attrs("twin", twin.integrator, params, twin=twin.as_dict())
    return run.trajectory(twin.dt, attrs)
