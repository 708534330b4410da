"""The public core shared by every engine and the reference model.

``cipcore`` holds what the reduced model (``reduced/``), the rigid-body
engines (``cip/``) and the validation layer (``validation/``) all use, so that
none of them reaches into another's private names:

==============  ==============================================================
module          job
==============  ==============================================================
params          reduced-model parameters (alpha, beta, gamma, nu, tau, dt),
                paper constants, input checks (:class:`ParameterError`)
scenario        a simulation's setting as one value (:class:`Scenario`), what
                is recorded, how the work is spread, the engine under test
models          the balancing models as values (single, coupled, ...)
noise           the random feedback gain R = 1 + nu xi / sqrt(dt), one seeded
                stream per realisation
control_law     the delayed random-gain control u = beta R e(t - tau), eq. (5)
control_kernel  the law, the delay ring and the recording rule for numba kernels
control_warp    the law as a warp function (warp engines only)
seeds           the seed namespace: noise streams and every other random use
schema          the shared time-series schema (:class:`Trajectory`) and
                recording checks
results         result types shared by every engine (lambda1 with its CI)
stats           one Student-t confidence interval
driver          realisation blocks x time chunks across threads
engine          the engine interface (a :class:`typing.Protocol`) and its
                capabilities
registry        the registry of engines: name -> engine, installed or why not
==============  ==============================================================
"""

from .engine import Capabilities, Engine
from .models import MODELS, BalanceModel, get_model
from .noise import ArrayNoise, GainNoise, random_gain
from .params import PAPER, BalanceParams, ParameterError
from .registry import engine_names, get_engine
from .results import LyapunovResult
from .schema import COMMON_FIELDS, UNITS, Trajectory

__all__ = [
    "COMMON_FIELDS",
    "MODELS",
    "PAPER",
    "UNITS",
    "ArrayNoise",
    "BalanceModel",
    "BalanceParams",
    "Capabilities",
    "Engine",
    "GainNoise",
    "LyapunovResult",
    "ParameterError",
    "Trajectory",
    "engine_names",
    "get_engine",
    "get_model",
    "random_gain",
]
