"""The paper's reduced linear balancing models (Yoshida, Higeta & Watanabe 2011, section 2).

Single balancer (eq. (3)) and two balancers coupled through a rigid
rod between the stick tips (eq. (5)), under time-delayed feedback with a
white-noise random gain R_i(t) = 1 + nu*xi_i(t).
"""

from cipcore.noise import ArrayNoise, GainNoise, random_gain
from cipcore.params import PAPER, BalanceParams, ParameterError
from cipcore.results import LyapunovResult
from cipcore.schema import COMMON_FIELDS, UNITS, Trajectory
from cipcore.stats import mean_ci95

from .lyapunov import CriticalGain, critical_gain, lyapunov, lyapunov_gains
from .simulate import n_controllers, simulate
from .stability import (
    characteristic_function,
    characteristic_roots,
    delay_system,
    discrete_exponent,
    rightmost_root,
    stability_region,
)

__all__ = [
    "COMMON_FIELDS",
    "PAPER",
    "UNITS",
    "ArrayNoise",
    "BalanceParams",
    "CriticalGain",
    "GainNoise",
    "LyapunovResult",
    "ParameterError",
    "Trajectory",
    "characteristic_function",
    "characteristic_roots",
    "critical_gain",
    "delay_system",
    "discrete_exponent",
    "lyapunov",
    "lyapunov_gains",
    "mean_ci95",
    "n_controllers",
    "random_gain",
    "rightmost_root",
    "simulate",
    "stability_region",
]
