"""Parameters of the reduced balancing models and their validation.

The reduced models are eqs. ((3)) and ((5)) of Yoshida, Higeta &
Watanabe (2011), section 2.  All quantities are per unit mass:

==========  ==========  =====================================================
name        unit        meaning
==========  ==========  =====================================================
alpha       1/s^2       gravitational (destabilising) stiffness, g/L
beta        1/s^2       feedback gain of the delayed controller
gamma       1/s         viscous damping of tip and base
nu          s^(1/2)     strength of the multiplicative white noise,
                        R(t) = 1 + nu*xi(t)
tau         s           feedback delay (a whole number of steps dt)
dt          s           integration time step
==========  ==========  =====================================================
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, replace
from typing import Any

STEPPERS = ("semi-implicit", "explicit")

#: The bob-to-cart mass ratio m/M of the rigid body (the cart 1 kg): MuJoCo refuses a
#: body lighter than its mjMINVAL (1e-15 kg), and the reduced model's reduction neglects
#: m/M, so a bob heavier than the cart is outside the model.  The command line's domain
#: (``validation.cli.domains``) and :meth:`cip.model.CIPParams.from_reduced` read it.
MASS_RATIO_RANGE = (1e-12, 1.0)
#: The paper's parameters (section 2.2): gamma = 50, alpha = 22, nu = 0.6, tau = 0.1.
PAPER = {"alpha": 22.0, "gamma": 50.0, "nu": 0.6, "tau": 0.1, "dt": 1e-3}


class ParameterError(ValueError):
    """A user-facing parameter is out of its allowed range.

    The message is one line and names the parameter and the allowed range.
    """


class EngineError(RuntimeError):
    """An engine broke: its process exited, hung past its timeout or broke its protocol.

    The message is one line and names the engine; the command exits 4.
    """


def check_positive(name: str, value: Any, *, allow_zero: bool = False) -> float:
    """Return ``value`` as a float, or raise :class:`ParameterError`.

    Rejects NaN, infinities, negatives and (unless ``allow_zero``) zero.
    """
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ParameterError(f"{name} must be a number, got {value!r}") from None
    bound = ">= 0" if allow_zero else "> 0"
    if not math.isfinite(v) or v < 0 or (v == 0 and not allow_zero):
        raise ParameterError(f"{name} must be finite and {bound}, got {value!r}")
    return v


def check_count(name: str, value: Any, minimum: int = 1) -> int:
    """Return ``value`` as an int ``>= minimum`` or raise :class:`ParameterError`."""
    try:
        iv = int(value)
    except (TypeError, ValueError):
        raise ParameterError(f"{name} must be an integer >= {minimum}, got {value!r}") from None
    if iv != value and not (isinstance(value, float) and value.is_integer()):
        raise ParameterError(f"{name} must be an integer >= {minimum}, got {value!r}")
    if iv < minimum:
        raise ParameterError(f"{name} must be an integer >= {minimum}, got {value!r}")
    return iv


def check_choice(name: str, value: str, choices: tuple[str, ...]) -> str:
    if value not in choices:
        raise ParameterError(f"{name} must be one of {', '.join(choices)}; got {value!r}")
    return value


def whole_steps(name: str, duration: float, dt: float) -> int:
    """Number of steps ``duration / dt``, which must be a whole number.

    Raises :class:`ParameterError` when ``duration`` is not a multiple of ``dt``
    to within 1e-9 relative.
    """
    n = duration / dt
    if not math.isfinite(n):  # a duration whose step count overflows float64
        raise ParameterError(
            f"{name} = {duration!r} s over dt = {dt!r} s is beyond any count of time steps"
        )
    k = round(n)
    if abs(n - k) > 1e-9 * max(1.0, abs(n)):
        raise ParameterError(
            f"{name} = {duration!r} s must be a whole number of time steps dt = {dt!r} s "
            f"(got {n:.6g} steps)"
        )
    return int(k)


@dataclass(frozen=True)
class BalanceParams:
    """Parameters of the delayed random-gain balancer (paper section 2).

    Attributes are validated on construction; see the module docstring for
    units.  ``beta`` has no default: it is the quantity the paper varies.
    """

    beta: float
    alpha: float = PAPER["alpha"]
    gamma: float = PAPER["gamma"]
    nu: float = PAPER["nu"]
    tau: float = PAPER["tau"]
    dt: float = PAPER["dt"]

    def __post_init__(self) -> None:
        object.__setattr__(self, "beta", check_positive("beta", self.beta, allow_zero=True))
        object.__setattr__(self, "alpha", check_positive("alpha", self.alpha, allow_zero=True))
        object.__setattr__(self, "gamma", check_positive("gamma", self.gamma, allow_zero=True))
        object.__setattr__(self, "nu", check_positive("nu", self.nu, allow_zero=True))
        object.__setattr__(self, "tau", check_positive("tau", self.tau))
        object.__setattr__(self, "dt", check_positive("dt", self.dt))
        if self.dt > self.tau:
            raise ParameterError(f"dt must be <= tau = {self.tau} s, got {self.dt}")
        whole_steps("tau", self.tau, self.dt)

    @property
    def delay_steps(self) -> int:
        """The delay tau in steps, d = tau / dt (an integer >= 1)."""
        return whole_steps("tau", self.tau, self.dt)

    @property
    def noise_scale(self) -> float:
        """Euler–Maruyama factor nu / sqrt(dt) of the held random gain (:mod:`cipcore.noise`)."""
        return self.nu / math.sqrt(self.dt)

    @property
    def law(self) -> tuple[float, float, float, float, float]:
        """(alpha, beta, gamma, noise_scale, dt): the constants of eqs. (3) and (5) in the
        order the compiled kernels take them (:mod:`reduced._kernels`)."""
        return (self.alpha, self.beta, self.gamma, self.noise_scale, self.dt)

    def with_(self, **changes: float) -> BalanceParams:
        """A copy with some parameters changed (validated again)."""
        return replace(self, **changes)

    def as_dict(self) -> dict[str, float]:
        return asdict(self)
