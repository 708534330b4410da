"""Linearisation of the MuJoCo CIP about upright, in the reduced model's coordinates.

Continuous time, x' = A x + B u, u = cart force / M (m/s^2, the reduced model's
control).  A and B come from central finite differences of MuJoCo's ``qacc``
(``mj_forward``; solver tolerance 1e-12 in the generated model so the numbers
are physics, not solver noise), then are transformed to

* single:   x = (x_T, x_M, x_T', x_M'),                 x_T = x_M + L theta
* coupled:  x = (q_T, q_M1, q_M2, delta, and rates),    q_T = (x_T1 + x_T2)/2,
            delta = x_T1 - x_T2 (the rod's stretch, zero for a rigid rod)

and compared with the reduced model's matrices (eqs. (3), (5)).
The rigid body differs from the reduced model by small terms, predicted here
to first order and checked by the tests:

* cart reaction: x_Mi'' gains -(m/M) alpha e_i;
* bob inertia kappa = I_bob / (m L^2): the tip row becomes
  (1 - kappa) * (reduced tip row) + kappa * (mean cart acceleration);
* coupled: the soft rod constraint is a stiff spring-damper on delta
  (delta'' ~ -k delta - b delta', k and b from solref/solimp).
"""

from __future__ import annotations

import copy
from dataclasses import dataclass

import mujoco
import numpy as np

from cip.model import CIPParams, bob_rotational_inertia, build
from cip.names import cart_joint, hinge_joint, motor, tip_site
from cipcore.models import get_model
from cipcore.params import BalanceParams


@dataclass
class Linearization:
    """Matrices in the reduced coordinates (see module docstring)."""

    model: str
    labels: list[str]
    A_full: np.ndarray
    B_full: np.ndarray
    A_reduced: np.ndarray
    B_reduced: np.ndarray
    A_extra: np.ndarray
    B_extra: np.ndarray
    rod_stiffness: float | None
    rod_damping: float | None

    @property
    def A_diff(self) -> np.ndarray:
        return self.A_full - self.A_reduced

    @property
    def residual(self) -> float:
        """max |A_full - A_reduced - A_extra| over the rows the reduced model has (1/s^2)."""
        k = len(self.reduced_index)
        a = (self.A_full - self.A_reduced - self.A_extra)[
            np.ix_(self.reduced_index, self.reduced_index)
        ]
        b = (self.B_full - self.B_reduced - self.B_extra)[self.reduced_index]
        del k
        return float(max(np.abs(a).max(), np.abs(b).max()))

    @property
    def reduced_index(self) -> list[int]:
        """Indices of the coordinates the reduced model has (all but delta)."""
        return [i for i, n in enumerate(self.labels) if "delta" not in n]


def qacc_jacobians(m: mujoco.MjModel, eps: float = 1e-6) -> tuple[np.ndarray, np.ndarray]:
    """Continuous A = [[0, I], [dqacc/dq, dqacc/dv]] and B = [[0], [dqacc/dctrl]] at qpos0.

    Central differences of ``mj_forward``'s qacc (hinge and slide joints only,
    so qpos and qvel have the same size).
    """
    d = mujoco.MjData(m)
    nv, nu = m.nv, m.nu

    def qacc(q, v, u):
        d.qpos[:] = q
        d.qvel[:] = v
        d.ctrl[:] = u
        mujoco.mj_forward(m, d)
        return d.qacc.copy()

    q0, v0, u0 = m.qpos0.copy(), np.zeros(nv), np.zeros(nu)
    dq = np.empty((nv, nv))
    dv = np.empty((nv, nv))
    du = np.empty((nv, nu))
    for j in range(nv):
        e = np.zeros(nv)
        e[j] = eps
        dq[:, j] = (qacc(q0 + e, v0, u0) - qacc(q0 - e, v0, u0)) / (2 * eps)
        dv[:, j] = (qacc(q0, v0 + e, u0) - qacc(q0, v0 - e, u0)) / (2 * eps)
    for j in range(nu):
        e = np.zeros(nu)
        e[j] = eps
        du[:, j] = (qacc(q0, v0, u0 + e) - qacc(q0, v0, u0 - e)) / (2 * eps)
    a = np.block([[np.zeros((nv, nv)), np.eye(nv)], [dq, dv]])
    b = np.vstack([np.zeros((nv, nu)), du])
    return a, b


def rod_jacobians(m: mujoco.MjModel, rod: str = "soft") -> tuple[np.ndarray, np.ndarray]:
    """Continuous A, B of the model file in MuJoCo's (qpos - qpos0, qvel) and ctrl, upright.

    ``rod`` is how the engine holds the rod between the tips (a single model has none):

    * ``"soft"``: the file's tendon equality with its solref/solimp, as MuJoCo solves it
      (its spring-damper is in ``qacc``: :func:`qacc_jacobians` of the file as it is);
    * ``"rigid"``: an exact distance constraint g(q) = |p_tip1 - p_tip2| - l = 0.  With
      the equality switched off, a0 = M^-1 Q is the unconstrained acceleration; the
      constraint force J^T lambda with J q'' = 0 (the rod carries no force at upright
      rest, so J's own variation is of second order) gives q'' = P a0,
      P = I - M^-1 J^T (J M^-1 J^T)^-1 J, and A = [[0, I], [P Aq, P Av]], B = [[0], [P Bu]].

    MuJoCo clamps the soft rod's time constant to at least 2 dt (``refsafe``); the
    shipped file's 2 ms equals 2 dt at dt = 1 ms, so its rod is the same at every
    refined step.
    """
    if rod == "soft" or m.neq == 0:
        return qacc_jacobians(m)
    if rod != "rigid":
        raise ValueError(f"rod must be 'soft' or 'rigid', got {rod!r}")
    free = copy.deepcopy(m)
    free.opt.disableflags |= mujoco.mjtDisableBit.mjDSBL_EQUALITY
    a0, b0 = qacc_jacobians(free)
    d = mujoco.MjData(m)
    mujoco.mj_forward(m, d)
    nv = m.nv
    mass = np.zeros((nv, nv))
    mujoco.mj_fullM(m, d, mass)
    jac = []
    for i in (1, 2):
        j = np.zeros((3, nv))
        mujoco.mj_jacSite(
            m, d, j, None, mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_SITE, tip_site(i))
        )
        jac.append(j)
    s1, s2 = (
        d.site_xpos[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_SITE, tip_site(i))] for i in (1, 2)
    )
    u = (s1 - s2) / np.linalg.norm(s1 - s2)
    jrow = (u @ (jac[0] - jac[1]))[None, :]
    minv_jt = np.linalg.solve(mass, jrow.T)
    proj = np.eye(nv) - minv_jt @ np.linalg.solve(jrow @ minv_jt, jrow)
    a = a0.copy()
    a[nv:] = proj @ a0[nv:]
    b = b0.copy()
    b[nv:] = proj @ b0[nv:]
    return a, b


def reduced_matrices(model: str, params: BalanceParams) -> tuple[np.ndarray, np.ndarray]:
    """A, B of the reduced model in the coordinates of :func:`linearize` (no delta)."""
    a_, g = params.alpha, params.gamma
    if get_model(model).n_controllers == 1:
        # (x_T, x_M, v_T, v_M)
        A = np.zeros((4, 4))
        A[0, 2] = A[1, 3] = 1.0
        A[2, 0], A[2, 1], A[2, 2] = a_, -a_, -g
        A[3, 3] = -g
        B = np.zeros((4, 1))
        B[3, 0] = 1.0
        return A, B
    # (q_T, q_M1, q_M2, v_T, v_M1, v_M2)
    A = np.zeros((6, 6))
    A[0, 3] = A[1, 4] = A[2, 5] = 1.0
    A[3, 0], A[3, 1], A[3, 2], A[3, 3] = a_, -a_ / 2, -a_ / 2, -g
    A[4, 4] = A[5, 5] = -g
    B = np.zeros((6, 2))
    B[4, 0] = B[5, 1] = 1.0
    return A, B


def linearize(model: str, physical: CIPParams | None = None, eps: float = 1e-6) -> Linearization:
    """Linearise the MuJoCo CIP and set it beside the reduced model (module docstring)."""
    p = physical or CIPParams()
    m = build(model, p)
    a_full, b_full = qacc_jacobians(m, eps)
    L, M = p.pendulum_length, p.cart_mass
    names = [mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_JOINT, j) for j in range(m.njnt)]
    nc = get_model(model).n_controllers
    ix = [m.jnt_dofadr[names.index(cart_joint(i + 1))] for i in range(nc)]
    it = [m.jnt_dofadr[names.index(hinge_joint(i + 1))] for i in range(nc)]
    iu = [mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_ACTUATOR, motor(i + 1)) for i in range(nc)]
    nv = m.nv
    # position map P: reduced-coordinate positions = P @ qpos (and the same for rates)
    P = np.zeros((nv, nv))
    if nc == 1:
        labels = ["x_T", "x_M"]
        P[0, ix[0]], P[0, it[0]] = 1.0, L
        P[1, ix[0]] = 1.0
    else:
        labels = ["q_T", "q_M1", "q_M2", "delta"]
        for i in range(2):
            P[0, ix[i]] += 0.5
            P[0, it[i]] += 0.5 * L
        P[1, ix[0]] = 1.0
        P[2, ix[1]] = 1.0
        P[3, ix[0]], P[3, it[0]], P[3, ix[1]], P[3, it[1]] = 1.0, L, -1.0, -L
    labels = labels + [f"{n}'" for n in labels]
    T = np.kron(np.eye(2), P)
    A = T @ a_full @ np.linalg.inv(T)
    B = (T @ b_full)[:, iu] * M  # per unit cart mass: u = F / M

    params = BalanceParams(
        beta=0.0, alpha=p.gravity / L, gamma=p.tip_damping, nu=0.0, tau=p.timestep,
        dt=p.timestep,
    )  # fmt: skip
    a_red, b_red = reduced_matrices(model, params)
    n = 2 * nv
    keep = [i for i, lab in enumerate(labels) if "delta" not in lab]
    A_red = np.zeros((n, n))
    B_red = np.zeros((n, nc))
    A_red[np.ix_(keep, keep)] = a_red
    B_red[keep] = b_red
    if p.cart_damping != p.tip_damping:
        for i in range(nc):
            A_red[nv + 1 + i, nv + 1 + i] = -p.cart_damping

    # predicted extra terms (first order in m/M and kappa)
    mr = p.mass_ratio
    kappa = bob_rotational_inertia(p) / (p.tip_mass * L**2)
    alpha = p.gravity / L
    A_extra = np.zeros((n, n))
    B_extra = np.zeros((n, nc))
    tip = nv  # the (mean) tip acceleration row
    for i in range(nc):
        cart = nv + 1 + i
        # e_i = x_Ti - x_Mi with x_Ti = q_T (+/- delta/2 in the coupled model)
        A_extra[cart, 0] -= mr * alpha
        A_extra[cart, 1 + i] += mr * alpha
    cart_rows = [nv + 1 + i for i in range(nc)]
    A_extra[tip] = -kappa * A_red[tip] + kappa * A_red[cart_rows].mean(axis=0)
    B_extra[tip] = kappa * B_red[cart_rows].mean(axis=0)
    k = b = None
    if nc == 2:
        di = labels.index("delta")
        k = float(-A[nv + di, di])
        b = float(-A[nv + di, nv + di])
    return Linearization(
        model=model, labels=labels, A_full=A, B_full=B, A_reduced=A_red, B_reduced=B_red,
        A_extra=A_extra, B_extra=B_extra, rod_stiffness=k, rod_damping=b,
    )  # fmt: skip


def transition_check(model: str, physical: CIPParams | None = None) -> float:
    """max |A_d - A_d(Euler from A)| where A_d is ``mjd_transitionFD``'s discrete A.

    Under MuJoCo's semi-implicit Euler with explicit damping the one-step map of
    the continuous A is [[I + h^2 Aq, h (I + h Av)], [h Aq, I + h Av]]; this
    returns the largest deviation, a cross-check of :func:`qacc_jacobians`
    against MuJoCo's own derivative routine.
    """
    p = physical or CIPParams()
    m = build(model, p)
    d = mujoco.MjData(m)
    mujoco.mj_forward(m, d)
    nv = m.nv
    ad = np.zeros((2 * nv, 2 * nv))
    mujoco.mjd_transitionFD(m, d, 1e-6, True, ad, None, None, None)
    a, _ = qacc_jacobians(m)
    h = m.opt.timestep
    aq, av = a[nv:, :nv], a[nv:, nv:]
    eye = np.eye(nv)
    pred = np.block([[eye + h * h * aq, h * (eye + h * av)], [h * aq, eye + h * av]])
    return float(np.abs(ad - pred).max())
