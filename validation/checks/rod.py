"""The rod's stretch (tip 1 - tip 2) of the coupled model against the engine's exact twin.

Two kinds of twin rod (:class:`reduced.twin.TwinParams`):

* a rod with a regulariser R > 0 (MuJoCo's solref/solimp spring, Drake's SAP
  near-rigid row): the constraint force stretches it, the twin resolves the
  stretch, and the engine's stretch must match the twin's to a relative L2
  distance <= the engine's ``rod_tolerance``;
* a rod with R = 0 (Exudyn's index-3 and Simbody's acceleration-level rigid
  constraints, Bullet's velocity-level row without constraint-force mixing): no
  force stretches it, the twin's stretch is zero but for its own round-off, and
  a relative distance to it compares two round-offs.  The engine's stretch is
  then held to its RMS relative to the balancing error's RMS (dimensionless),
  <= the engine's ``rod_tolerance``: a rod that gives (a soft or missing rod, a
  wrong rod length) stretches by a fraction of the balancing error.
"""

from __future__ import annotations

import numpy as np

from validation.checks.metrics import relative_l2
from validation.checks.stats import FAIL, PASS, Check


def rod_check(
    model: str,
    stretch: np.ndarray,
    twin_stretch: np.ndarray,
    balancing_error: np.ndarray,
    twin,
    declared: tuple[str, float],
    details: str = "",
) -> Check:
    """The check ``twin.rod.<model>`` (rule in the module docstring).

    Parameters
    ----------
    stretch, twin_stretch : (R, T) tip 1 - tip 2 (m) of the engine and of its twin.
    balancing_error : (R, T, 2) the engine's balancing errors (m); the engine's run is
        complete when it has the twin's length and is finite everywhere (a run that
        stopped early fails).
    twin : the engine's :class:`reduced.twin.TwinParams`.
    declared : the engine's declared rod (``Capabilities.rod``) and its ``rod_tolerance``.
    details : the run's setting, said in the check.
    """
    rod, tolerance = declared
    complete = bool(
        stretch.shape[1] == twin_stretch.shape[1] and np.isfinite(balancing_error).all()
    )
    k = min(stretch.shape[1], twin_stretch.shape[1])
    sf, st = stretch[:, :k], twin_stretch[:, :k]
    nf, nt = np.linalg.norm(sf), np.linalg.norm(st)
    rms = float(nf / np.sqrt(sf.size))
    if twin.rod_regulariser > 0:
        value = relative_l2(sf, st)
        implied = twin.rod_stiffness * nt / nf if nf > 0 else float("inf")
        values = {
            "stretch_relative_l2": value,
            "stretch_rms_m": rms,
            "implied_stiffness": implied,
            "twin_stiffness": twin.rod_stiffness,
        }
        rule = (
            f"the rod's stretch (tip 1 - tip 2) matches the twin's {rod} constraint to "
            f"relative L2 <= {tolerance:g}; implied stiffness k_twin |d_twin| / |d_full|"
        )
    else:
        e_rms = float(np.sqrt(np.mean(np.square(balancing_error))))
        value = rms / e_rms if e_rms > 0 else float("inf")
        values = {
            "stretch_over_balancing_error": value,
            "stretch_rms_m": rms,
            "twin_stretch_rms_m": float(nt / np.sqrt(st.size)),
            "balancing_error_rms_m": e_rms,
        }
        rule = (
            "the twin's rod is rigid (no regulariser: its stretch is round-off); the rod's "
            f"stretch RMS over the balancing error's RMS <= {tolerance:g}"
        )
    ok = complete and bool(np.isfinite(value)) and value <= tolerance
    return Check(
        name=f"twin.rod.{model}",
        status=PASS if ok else FAIL,
        values=values,
        tolerance=rule,
        details=details,
    )
