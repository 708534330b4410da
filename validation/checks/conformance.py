"""Does a model file conform to what the reduced model assumes?  The declared specification.

The reduced models (paper eqs. (3) single and (5) coupled, section 2) describe
a massless cart-driven inverted pendulum: a point bob of negligible mass on a
massless pole, tip and base damped by gamma, a rigid rod joining the coupled
tips, the delayed random-gain force, nothing else.  A rigid-body file is a
faithful stand-in only if every term it adds is small; the exact twin
(:mod:`reduced.twin`) follows whatever the file says, so "the engine simulates
this file correctly" (the twin checks) and "this file is the paper's system"
(this module) are separate questions.  ``model.conforms.<model>`` lists every
item below with the file's value and the bound, and fails naming each
deviation; the file is still simulated and reported.

The bounds (SI units), each justified by the size of the term it admits:

* ``mass_ratio`` m/M <= 1e-3: the cart reaction makes alpha_eff = alpha (1 +
  m/M) (``cip-validate linearize``); 1e-3 is the shipped model's value and a
  0.1 % shift of alpha, the largest known term the full-vs-reduced margins
  allow.
* ``kappa`` = I_bob / (m L^2) <= 1e-5: the bob's inertia scales the tip row by
  (1 - kappa); 1e-5 keeps it 100 times below the cart reaction (a sphere of
  radius 0.5 % of L; the shipped point bob has 5e-9).
* ``com_at_tip``: the pendulum's centre of mass lies on site ``tip_<i>`` to
  1e-9 L (a bob at the tip; the reduced model has no distributed pole mass).
* ``rod_timeconst``: the rod's solref time constant (after MuJoCo's
  ``refsafe``, max(tc, 2 dt)) <= 2e-3 s, and ``rod_stiffness`` k = d / (dmax^2
  tc^2 zeta^2) >= 1e4 alpha = 2.2e5 1/s^2: the rod's stretch then follows the
  tips' relative force with a gain alpha / k <= 1e-4, so the tips move as one
  (the reduced model's q_T); solref 0.1 gives k = 1e2, far outside.
* ``rod_impedance``: solimp dmin and dmax >= 0.99 (the constraint applies at
  least 99 % of the force that holds the rod; the regulariser (1 - d)/d lets
  the rod give way by at most 1 %).
* ``rod_tendon``: the rod tendon has no stiffness, damping, friction loss or
  limit and its equality is active.
* ``joint_limits``: no slide joint is limited (the reduced model's base is
  free, and the cart's excursion grows with the run's duration, not bounded
  by the small-angle regime: a cart slide range of +-0.02 m engages in the
  quick amplitude scan); a hinge limit, if any, lies beyond +-pi/2 (the fallen
  pole of the divergence rule), so it never engages while the pole stands.
* ``joint_friction``, ``joint_armature``, ``joint_damping``,
  ``joint_stiffness``: all zero on every degree of freedom (the reduced model's
  only dissipation is gamma, supplied by the affine-bias actuators).
* ``degrees_of_freedom``: exactly a slide and a hinge per balancer.
* ``contacts``: no pair of geoms can collide (contact disabled, or no
  contype / conaffinity match, and no explicit pairs).
* ``fluid``: no fluid forces (density, viscosity, wind zero).
* ``gravity_compensation``: none; ``other_equalities``: none but the rod.
* ``actuator_dynamics``: every actuator is direct (dyntype none: no filter,
  integrator or muscle state between the control and the force);
  ``actuator_gears``: every gear is (1, 0, 0, 0, 0, 0); ``force_limits``:
  no control, force or actuator-force limit (the delayed random-gain force
  is unbounded).
* ``gravity``: along -z, and g/L equals the controller's alpha to 1e-12;
  ``tip_damping``, ``cart_damping``: equal the controller's gamma to 1e-12;
  ``timestep``: equals the controller's dt to 1e-12; ``integrator``: the one
  the twin steps (``Euler``, MuJoCo's semi-implicit Euler, like the reduced
  semi-implicit stepper).

:func:`envelope_twin_terms` is the twin at the specification's corner (the
largest known terms a conforming file can have): the full-vs-reduced margins
(:mod:`validation.checks.agreement`) admit the file's known terms only up to it.
"""

from __future__ import annotations

import math

import mujoco
import numpy as np

from cip.conformance import physical_content
from cipcore.params import BalanceParams
from cipcore.scenario import Execution, Recording, Scenario
from validation.checks.stats import FAIL, PASS, Check, t_half_width

MASS_RATIO_MAX = 1e-3
KAPPA_MAX = 1e-5
COM_OFFSET_MAX = 1e-9  # relative to L
ROD_TIMECONST_MAX = 2e-3  # s
ROD_STIFFNESS_PER_ALPHA = 1e4  # k >= 1e4 alpha
ROD_IMPEDANCE_MIN = 0.99
EQUAL_RTOL = 1e-12
#: the integrators the exact twin steps
TWIN_INTEGRATORS = ("Euler",)
#: 1 + this: round-off allowance on the "<=" bounds (compiled masses are sums)
_ROUND = 1e-9


def _item(value, bound: str, ok: bool) -> dict:
    return {"value": value, "bound": bound, "ok": bool(ok)}


def _equal(a: float, b: float) -> bool:
    return abs(a - b) <= EQUAL_RTOL * abs(b)


def spec_items(m: mujoco.MjModel, mapping, params: BalanceParams) -> dict[str, dict]:
    """Every item of the specification with the file's value, the bound and ok.

    ``mapping`` is the file's :class:`cip.mjcf_params.ModelMapping`, ``params``
    the controller's (alpha, gamma, dt).

    The function is long because it is the specification's table, one item per clause.
    """
    nc = mapping.n_controllers
    c = physical_content(m, nc)
    L = mapping.pendulum_length
    items: dict[str, dict] = {}
    items["mass_ratio"] = _item(
        mapping.mass_ratio,
        f"m/M <= {MASS_RATIO_MAX:g}",
        mapping.mass_ratio <= MASS_RATIO_MAX * (1 + _ROUND),
    )
    items["kappa"] = _item(
        mapping.kappa, f"I_bob/(m L^2) <= {KAPPA_MAX:g}", mapping.kappa <= KAPPA_MAX
    )
    off = max(b.com_offset for b in c.balancers)
    items["com_at_tip"] = _item(
        off, f"|centre of mass - tip site| <= {COM_OFFSET_MAX:g} L", off <= COM_OFFSET_MAX * L
    )
    if nc == 2:
        rod = mapping.rod_constants()
        items["rod_timeconst"] = _item(
            rod["timeconst"],
            f"<= {ROD_TIMECONST_MAX:g} s",
            rod["timeconst"] <= ROD_TIMECONST_MAX * (1 + _ROUND),
        )
        kmin = ROD_STIFFNESS_PER_ALPHA * params.alpha
        items["rod_stiffness"] = _item(
            rod["stiffness"], f">= {kmin:.3g} 1/s^2 (1e4 alpha)", rod["stiffness"] >= kmin
        )
        d = min(mapping.solimp[0], mapping.solimp[1])
        items["rod_impedance"] = _item(
            list(mapping.solimp), f"dmin, dmax >= {ROD_IMPEDANCE_MIN}", d >= ROD_IMPEDANCE_MIN
        )
        r = c.rod or {}
        bad = [k for k in ("stiffness", "damping", "frictionloss") if r.get(k, 0.0)]
        bad += [k for k in ("limited",) if r.get(k)]
        bad += [] if r.get("equality_active", False) else ["equality inactive"]
        items["rod_tendon"] = _item(
            bad or "none", "no stiffness, damping, friction loss, limit; equality active", not bad
        )
    slide, hinge = int(mujoco.mjtJoint.mjJNT_SLIDE), int(mujoco.mjtJoint.mjJNT_HINGE)
    limits = {}
    for name, j in c.joints.items():
        if not j["limited"]:
            continue
        if j["type"] == slide or not (
            j["range_low"] <= -math.pi / 2 and j["range_high"] >= math.pi / 2
        ):
            limits[name] = [j["range_low"], j["range_high"]]
    items["joint_limits"] = _item(
        limits or "none", "no slide limit; hinge limits beyond +-pi/2 rad", not limits
    )
    for key, what in (
        ("frictionloss", "joint_friction"),
        ("armature", "joint_armature"),
        ("damping", "joint_damping"),
        ("stiffness", "joint_stiffness"),
    ):
        nz = {n: j[key] for n, j in c.joints.items() if j[key] != 0.0}
        items[what] = _item(nz or 0.0, f"{key} = 0 on every joint", not nz)
    kinds = sorted(j["type"] for j in c.joints.values())
    want = sorted([slide, hinge] * nc)
    items["degrees_of_freedom"] = _item(
        {"joints": len(c.joints), "nv": int(m.nv)},
        f"one slide and one hinge per balancer ({2 * nc} joints)",
        kinds == want and m.nv == 2 * nc,
    )
    items["contacts"] = _item(
        {"possible": c.contact_possible, "pairs": c.contact_pairs},
        "no geom pair can collide",
        not c.contact_possible and c.contact_pairs == 0,
    )
    items["fluid"] = _item(c.fluid, "density = viscosity = wind = 0", not any(c.fluid.values()))
    items["gravity_compensation"] = _item(c.gravcomp, "0", c.gravcomp == 0.0)
    items["other_equalities"] = _item(
        c.other_equalities or "none", "only the rod", not c.other_equalities
    )
    dyn = {n: a["dyntype"] for n, a in c.actuators.items() if a["dyntype"] != 0}
    items["actuator_dynamics"] = _item(dyn or "none", "dyntype none (direct force)", not dyn)
    unit = [1.0, 0, 0, 0, 0, 0]
    gears = {n: a["gear"] for n, a in c.actuators.items() if a["gear"] != unit}
    items["actuator_gears"] = _item(gears or "all unit", "gear (1, 0, 0, 0, 0, 0)", not gears)
    lim = [
        n
        for n, a in c.actuators.items()
        if a["ctrllimited"] or a["forcelimited"] or a["actlimited"]
    ]
    lim += [n for n, j in c.joints.items() if j["actfrclimited"]]
    items["force_limits"] = _item(lim or "none", "no control or force limits", not lim)
    g = c.gravity
    items["gravity"] = _item(
        {"g": list(g), "alpha": mapping.alpha},
        f"along -z, g/L = alpha = {params.alpha:g} 1/s^2",
        g[0] == 0 and g[1] == 0 and _equal(mapping.alpha, params.alpha),
    )
    items["tip_damping"] = _item(
        mapping.tip_damping,
        f"= gamma = {params.gamma:g} 1/s",
        _equal(mapping.tip_damping, params.gamma),
    )
    items["cart_damping"] = _item(
        mapping.cart_damping,
        f"= gamma = {params.gamma:g} 1/s",
        _equal(mapping.cart_damping, params.gamma),
    )
    items["timestep"] = _item(
        mapping.timestep, f"= dt = {params.dt:g} s", _equal(mapping.timestep, params.dt)
    )
    items["integrator"] = _item(
        mapping.integrator, " or ".join(TWIN_INTEGRATORS), mapping.integrator in TWIN_INTEGRATORS
    )
    return items


def conformance_check(model: str, path: str, params: BalanceParams) -> Check:
    """``model.conforms.<model>``: every specification item of the file at ``path``."""
    from cip.mjcf_params import load_model_file, read_mapping

    m = load_model_file(path)
    mp = read_mapping(m)
    items = spec_items(m, mp, params)
    bad = [k for k, v in items.items() if not v["ok"]]
    why = "; ".join(f"{k} = {items[k]['value']} (bound: {items[k]['bound']})" for k in bad)
    return Check(
        name=f"model.conforms.{model}",
        status=FAIL if bad else PASS,
        values=items,
        tolerance="every item of the specification of the reduced model's assumptions "
        "(validation.checks.conformance; bounds justified in its docstring and the README)",
        details=(f"outside the specification: {why}" if bad else "every item inside")
        + f"; file {path}",
    )


def conformance_checks(files: dict[str, str] | None, models: tuple[str, ...]) -> list[Check]:
    """``model.conforms`` for each model's file (a user's ``--mjcf`` or the shipped one)."""
    from cip.mjcf_params import shipped_model_path
    from validation.profiles import PAPER_BETA

    return [
        conformance_check(
            model,
            str((files or {}).get(model) or shipped_model_path(model)),
            BalanceParams(beta=PAPER_BETA[model]),
        )
        for model in models
    ]


def envelope_twin_terms(model: str, params: BalanceParams, integrator: str = "Euler") -> dict:
    """Keyword arguments of :class:`reduced.twin.TwinParams` at the specification's corner.

    The controller's alpha, gamma and dt, m/M = ``MASS_RATIO_MAX``, kappa =
    ``KAPPA_MAX``; coupled: the softest conforming rod (stiffness 1e4 alpha,
    damping 2 / (dmax tc) at tc = 2e-3 s and dmax = 0.99, regulariser (1 - d)/d
    times the tendon's inverse weight ~ 2 / m, per unit M: 2 (1 - d) / (d m/M)).
    ``integrator``: the stepper of the engine's own twin (MuJoCo's names), a
    physical setting of the run, so the envelope admits its difference from the
    reduced model's semi-implicit Euler as a known term.
    """
    from cipcore.models import get_model

    out = {
        "alpha": params.alpha,
        "gamma_tip": params.gamma,
        "gamma_cart": params.gamma,
        "mass_ratio": MASS_RATIO_MAX,
        "kappa": KAPPA_MAX,
        "dt": params.dt,
        "integrator": integrator,
    }
    if get_model(model).n_controllers == 2:
        d = ROD_IMPEDANCE_MIN
        out.update(
            rod=True,
            rod_stiffness=ROD_STIFFNESS_PER_ALPHA * params.alpha,
            rod_damping=2.0 / (d * ROD_TIMECONST_MAX),
            rod_regulariser=2.0 * (1.0 - d) / (d * MASS_RATIO_MAX),
        )
    return out


def bounded_margin(
    full: np.ndarray,
    reference: np.ndarray,
    expected: np.ndarray,
    envelope: np.ndarray,
    floor: float = 0.0,
) -> float:
    """The paired-equivalence margin with the known terms bounded by the specification.

    As :func:`validation.checks.stats.paired_equivalence` with ``expected`` (the file's
    twin minus the reduced model): |mean e| + hw(e) + hw(d) + floor, except that
    the known terms' part |mean e| + hw(e) is at most the envelope twin's
    (:func:`envelope_twin_terms`): a file outside the specification cannot
    widen the margin beyond what a conforming file can produce.
    """

    def known(x: np.ndarray) -> float:
        x = np.asarray(x, dtype=float).ravel()
        x = x[np.isfinite(x)]
        return abs(float(x.mean())) + t_half_width(x) if x.size > 1 else float("inf")

    a = np.asarray(full, dtype=float).ravel()
    b = np.asarray(reference, dtype=float).ravel()
    ok = np.isfinite(a) & np.isfinite(b)
    d = a[ok] - b[ok]
    hw = t_half_width(d) if d.size > 1 else float("nan")
    return min(known(expected), known(envelope)) + hw + floor


def run_envelope_twin(
    scenario: Scenario, *, recording: Recording, threads: int | None, integrator: str = "Euler"
):
    """The twin at the specification's corner under the same noise as the file's twin
    (the same scenario), stepped by ``integrator`` (the engine twin's)."""
    from reduced.twin import TwinParams, simulate_twin

    tw = TwinParams(**envelope_twin_terms(scenario.model, scenario.params, integrator))
    return simulate_twin(scenario, tw, recording=recording, execution=Execution(threads=threads))


#: Margin rule when the known terms are bounded by the specification.
BOUNDED_RULE = (
    "paired TOST: 95% CI of the per-realisation full - reduced difference within +- margin, "
    "margin = min(|twin - reduced|, |envelope twin - reduced|) (the known terms, paired mean + "
    "95% half-width, at most what a model inside the specification produces) + the paired "
    "95% half-width; inconclusive states the realisations needed"
)
