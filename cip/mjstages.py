"""MuJoCo pipeline stages a model cannot use, switched off while cipval steps it.

MuJoCo runs its constraint stage (``mj_makeConstraint``, island discovery, the
solver) at every step, also when a model has nothing for it to do.  For a model
whose constraints cannot change from step to step, two of those stages are pure
overhead:

* a model that can have no constraint at all (no equality, no joint or tendon
  limit, no friction loss, no flex, contacts disabled) computes the same
  accelerations with ``mjDSBL_CONSTRAINT``: the single CIP;
* a model whose constraints are equalities only (the same rows at every step,
  none state-dependent) and form a single island holding every degree of
  freedom solves the same linear system with ``mjDSBL_ISLAND``: the island is
  the whole system, and discovering it and gathering its island-local vectors
  is repeated at every step for nothing: the coupled CIP, whose rod equality
  joins the two carts' kinematic trees.

:func:`unused_stage_flags` returns those flags for a model, from its arrays
alone (the island test steps nothing: ``mj_forward`` once on a fresh
``MjData``); a model with any limit, friction loss, flex or enabled contact gets
none.  The states stay bit-identical (``tests/test_mjstages.py`` steps both
shipped models with and without the flags under the delayed random-gain
controller; for another single-island model the solve is the same system with
its degrees of freedom possibly in another order: round-off at most), and the
steps cost less: ``python benchmarks/bench_mujoco.py --stages``
(``mujoco.rollout`` on one thread, timers and sensors off as the runner steps,
16 realisations x 2000 steps, median of 9 alternated; mujoco 4.0, 2 December 2026)
gave 1.26 -> 1.04 us per single-CIP step with ``mjDSBL_CONSTRAINT`` (0.82) and
2.53 -> 2.21 us per coupled step with ``mjDSBL_ISLAND`` (0.87).  Every other
disable flag, tried one at a time, either changed the states (warm start,
gravity, actuation) or gained no more than the noise (about 3 %).
"""

from __future__ import annotations

import mujoco
import numpy as np

_DSBL = mujoco.mjtDisableBit


def _state_dependent_constraints(m: mujoco.MjModel) -> bool:
    """Whether ``m`` can have constraint rows that come and go with the state
    (contacts, limits, friction loss, flex)."""
    contacts = not (m.opt.disableflags & _DSBL.mjDSBL_CONTACT) and m.ngeom > 0
    limited = bool(np.any(m.jnt_limited) or np.any(m.tendon_limited))
    friction = bool(np.any(m.dof_frictionloss > 0) or np.any(m.tendon_frictionloss > 0))
    return contacts or limited or friction or m.nflex > 0


def unused_stage_flags(m: mujoco.MjModel) -> int:
    """``mjtDisableBit`` flags of the stages ``m`` cannot use (0 where none).

    ``mjDSBL_CONSTRAINT`` when ``m`` can have no constraint; ``mjDSBL_ISLAND`` when
    its constraints are equalities only, forming one island over every degree of
    freedom (``nisland == 1`` and ``nidof == nv`` after ``mj_forward``).
    """
    if m.opt.disableflags & _DSBL.mjDSBL_CONSTRAINT or _state_dependent_constraints(m):
        return 0
    if m.neq == 0:
        return int(_DSBL.mjDSBL_CONSTRAINT)
    if m.opt.disableflags & _DSBL.mjDSBL_ISLAND:
        return 0
    d = mujoco.MjData(m)
    mujoco.mj_forward(m, d)
    return int(_DSBL.mjDSBL_ISLAND) if d.nisland == 1 and d.nidof == m.nv else 0
