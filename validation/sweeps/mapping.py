"""Parameter mapping: one grid point's settings -> the engine's parameters."""

from __future__ import annotations

from typing import Any

from cipcore.models import get_model
from cipcore.params import BalanceParams, ParameterError
from cipcore.registry import get_engine
from validation.profiles import PAPER_BETA

REDUCED_KEYS = ("beta", "alpha", "gamma", "nu", "tau", "dt")
PHYSICAL_KEYS = (
    "rod_length", "rod_length_ratio", "mass_ratio", "rod_mass", "bob_radius",
    "solref_timeconst", "solref_dampratio", "solimp_width", "integrator",
)  # fmt: skip
#: settings of the rod joining two sticks' tips (no effect on a one-stick model)
ROD_KEYS = ("rod_length", "rod_length_ratio", "rod_mass")
RUN_KEYS = ("amplitude",)
SETTINGS = REDUCED_KEYS + PHYSICAL_KEYS + RUN_KEYS
#: settings whose values are words, not numbers
WORD_SETTINGS = ("integrator",)
#: the declared domain (:data:`validation.cli.domains.DOMAINS`) of a setting that has one,
#: the same as its command-line option's; the others are finite numbers, checked again
#: where they are used (:class:`cip.model.CIPParams`)
SETTING_DOMAINS = {"beta": "beta", "alpha": "alpha", "gamma": "gamma", "nu": "nu",
                   "tau": "tau", "dt": "dt", "amplitude": "amplitude",
                   "rod_length": "rod length", "mass_ratio": "mass ratio"}  # fmt: skip

#: initial balancing error (m) of a study that does not set ``amplitude``
DEFAULT_AMPLITUDE = 1e-3
#: bob / cart mass m/M of a study that does not set ``mass_ratio``
DEFAULT_MASS_RATIO = 1e-3


def point_params(study: Any, point: dict[str, Any], beta: float | None = None):
    """(BalanceParams, CIPParams or None, amplitude) of one grid point of ``study``.

    ``study`` is a :class:`validation.sweeps.study.Study` (its ``model``,
    ``engine`` and ``fixed`` settings; a ``compare`` study's point names its model).

    The physical parameters (:class:`cip.model.CIPParams`) are built for an
    engine with ``capabilities.rigid_body``; beta is ``beta`` when given (a
    study's target gain beta*, 1/s^2), else the study's, else the paper's gain
    for lambda1 = 5e-4 (:data:`validation.profiles.PAPER_BETA`).
    """
    s = {**study.fixed, **point}
    red = {k: float(s[k]) for k in REDUCED_KEYS if k in s}
    if beta is not None:
        red["beta"] = float(beta)
    red.setdefault("beta", PAPER_BETA[get_model(study.model_of(point)).name])
    params = BalanceParams(**red)
    amplitude = float(s.get("amplitude", DEFAULT_AMPLITUDE))
    phys = None
    if get_engine(study.engine).capabilities.rigid_body:
        from cip.model import CIPParams

        kw: dict[str, Any] = {}
        if "rod_length" in s and "rod_length_ratio" in s:
            raise ParameterError("set rod_length or rod_length_ratio, not both")
        if "rod_length" in s:
            kw["rod_length"] = float(s["rod_length"])
        if "rod_length_ratio" in s:
            if not params.alpha > 0:
                raise ParameterError("rod_length_ratio needs alpha > 0 (L = g / alpha)")
            kw["rod_length"] = (
                float(s["rod_length_ratio"]) * CIPParams.from_reduced(params).pendulum_length
            )
        for k in ("rod_mass", "bob_radius"):
            if k in s:
                kw[k] = float(s[k])
        if "integrator" in s:
            kw["integrator"] = str(s["integrator"])
        base = CIPParams()
        sr = list(base.solref)
        si = list(base.solimp)
        if "solref_timeconst" in s:
            sr[0] = float(s["solref_timeconst"])
        if "solref_dampratio" in s:
            sr[1] = float(s["solref_dampratio"])
        if "solimp_width" in s:
            si[2] = float(s["solimp_width"])
        kw["solref"], kw["solimp"] = tuple(sr), tuple(si)
        mass_ratio = float(s.get("mass_ratio", DEFAULT_MASS_RATIO))
        phys = CIPParams.from_reduced(params, mass_ratio=mass_ratio, **kw)
        if not abs(amplitude) < phys.pendulum_length:
            raise ParameterError(
                f"amplitude must be < L = {phys.pendulum_length:.4g} m, got {amplitude}"
            )
    return params, phys, amplitude
