"""Steps of the exact linear twin for engines that are not MuJoCo (numba, cached).

:mod:`reduced._twin_kernel` steps MuJoCo's integrators; this module adds the
schemes that other engines declare (see :mod:`reduced.twin` for the
equations).  Coordinates per balancer i: the cart position x_i (m) and the
balancing error e_i (m), rates v_i, w_i; forces per unit cart mass M.  The
control u_i and the dampers are evaluated at the start of the step and held
over it (the engines apply them as constant loads: unlike MuJoCo's RK4, whose
affine-bias dampers are re-evaluated at every stage); gravity and the rod are
the engine's own and follow the stages.

* ``Newmark`` (scheme 3, Exudyn's ``MainSolverImplicitSecondOrder`` with
  ``useNewmark``, beta = 1/2, gamma = 1): the implicit step

      M a+ = F_n + K q+ + J^T lambda,   v+ = v + h a+,
      q+ = q + h v + (h^2 / 2) a+,      J q+ = 0,

  K q = (0, mu alpha e) the gravity term at the new positions, F_n the held
  control and dampers, and the rod (coupled model) a rigid index-3 constraint on
  the tip separation (J = (+1, +1, -1, -1) in (x1, e1, x2, e2)) with its
  Lagrange multiplier lambda.  Linear, so one solve per step: with
  S = (M - (h^2/2) K)^-1, a+ = S (F_n + K (q + h v)) + S J^T lambda and
  lambda from J q+ = 0.
* ``RK-Merson`` (scheme 4, Simbody's ``RungeKuttaMersonIntegrator`` at a fixed
  step, Hairer-Norsett-Wanner's Table 4.1): five stages

      f1 = f(y0 + h/3 f0),  f2 = f(y0 + h/6 (f0 + f1)),
      f3 = f(y0 + h/8 (f0 + 3 f2)),  f4 = f(y0 + h/2 (f0 - 3 f2 + 4 f3)),
      y1 = y0 + h/6 (f0 + 4 f3 + f4),

  f(q, v) = (v, a) with a from the index-1 constrained equations (the rod's
  force from J a = 0).  Every stage keeps J v = 0 and J q constant, so Simbody's
  projection onto the constraint manifold after the step is the identity to
  first order in the angles.

numba's cache of the twin's kernels (:data:`reduced._twin_kernel.KERNELS`) does not see
edits to this file: after changing it, clear ``reduced/__pycache__`` (or edit the kernel).
"""

from __future__ import annotations

import numpy as np
from numba import njit

#: Runge-Kutta-Merson's Butcher table: stage j's state is y0 + h sum_k A[j, k] f_k ...
MERSON_A = np.array([
    [0.0, 0.0, 0.0, 0.0],
    [1.0 / 3.0, 0.0, 0.0, 0.0],
    [1.0 / 6.0, 1.0 / 6.0, 0.0, 0.0],
    [1.0 / 8.0, 0.0, 3.0 / 8.0, 0.0],
    [1.0 / 2.0, 0.0, -3.0 / 2.0, 2.0],
])  # fmt: skip
#: ... and the propagated 4th-order solution y0 + h sum_k B[k] f_k.
MERSON_B = np.array([1.0 / 6.0, 0.0, 0.0, 2.0 / 3.0, 1.0 / 6.0])


@njit(inline="always", cache=True, nogil=True)
def tip_separation(st: np.ndarray) -> tuple[float, float]:
    """The rod's coordinate delta = J q = (x_1 + e_1) - (x_2 + e_2) (m) and its rate J v (m/s)
    of a coupled state ``st`` (2, 4) [x, e, v, w], J = (+1, +1, -1, -1) in (x1, e1, x2, e2)."""
    sep = (st[0, 0] + st[0, 1]) - (st[1, 0] + st[1, 1])
    sep_rate = (st[0, 2] + st[0, 3]) - (st[1, 2] + st[1, 3])
    return sep, sep_rate


@njit(inline="always", cache=True, nogil=True)
def apply_rod_force(mat: np.ndarray, f: float, ax: np.ndarray, ae: np.ndarray) -> None:
    """Add the rod's force ``f`` (per unit M) along J^T, J = (+1, +1, -1, -1) in
    (x1, e1, x2, e2), through ``mat`` (2, 2), M^-1 or the step's matrix, to the
    accelerations ``ax``, ``ae`` (m/s^2) of the two balancers."""
    cx = (mat[0, 0] + mat[0, 1]) * f
    ce = (mat[1, 0] + mat[1, 1]) * f
    ax[0] += cx
    ae[0] += ce
    ax[1] -= cx
    ae[1] -= ce


@njit(cache=True, nogil=True)
def _held_forces(st: np.ndarray, u: np.ndarray, coef: np.ndarray, fx: np.ndarray, fe: np.ndarray):
    """The forces held over a step (per unit M) on x and e: control and dampers at ``st``."""
    g_tip, g_cart, mu = coef[1], coef[2], coef[3]
    for i in range(st.shape[0]):
        tip_drag = g_tip * mu * (st[i, 2] + st[i, 3])
        fx[i] = u[i] - g_cart * st[i, 2] - tip_drag
        fe[i] = -tip_drag


@njit(cache=True, nogil=True)
def _rigid_accelerations(
    st: np.ndarray,
    fx: np.ndarray,
    fe: np.ndarray,
    coef: np.ndarray,
    smat: np.ndarray,
    lead: float,
    target: float,
    ax: np.ndarray,
    ae: np.ndarray,
) -> None:
    """Accelerations (m/s^2) a = S (F + K (q + lead q')) + S J^T lambda with J a = ``target``.

    ``fx``, ``fe`` the held forces, ``smat`` S (per unit M), ``lead`` (s) where
    gravity's K is evaluated (0: at the stage's q; h: at Newmark's q + h v, the
    rest of q+ being in S).
    """
    nc = st.shape[0]
    alpha, mu = coef[0], coef[3]
    for i in range(nc):
        ge = fe[i] + mu * alpha * (st[i, 1] + lead * st[i, 3])
        ax[i] = smat[0, 0] * fx[i] + smat[0, 1] * ge
        ae[i] = smat[1, 0] * fx[i] + smat[1, 1] * ge
    if coef[7] > 0.5 and nc == 2:
        ja0 = (ax[0] + ae[0]) - (ax[1] + ae[1])
        lam = (target - ja0) / (2.0 * (smat[0, 0] + smat[0, 1] + smat[1, 0] + smat[1, 1]))
        apply_rod_force(smat, lam, ax, ae)


@njit(cache=True, nogil=True)
def newmark_step(st: np.ndarray, u: np.ndarray, coef: np.ndarray, smat: np.ndarray, h: float):
    """One Newmark step (beta = 1/2, gamma = 1) of ``st`` (C, 4) in place, rigid rod.

    ``smat`` is S = (M - (h^2/2) K)^-1 per unit M (:meth:`reduced.twin.TwinParams.step_matrix`).
    """
    nc = st.shape[0]
    ax = np.empty(nc)
    ae = np.empty(nc)
    fx = np.empty(nc)
    fe = np.empty(nc)
    _held_forces(st, u, coef, fx, fe)
    target = 0.0
    if nc == 2:
        # the rod at position level: J q+ = 0  <=>  J a+ = -2 (sep + h sep') / h^2
        sep, sep_rate = tip_separation(st)
        target = -2.0 * (sep + h * sep_rate) / (h * h)
    _rigid_accelerations(st, fx, fe, coef, smat, h, target, ax, ae)
    for i in range(nc):
        v, w = st[i, 2], st[i, 3]
        st[i, 0] += h * v + 0.5 * h * h * ax[i]
        st[i, 1] += h * w + 0.5 * h * h * ae[i]
        st[i, 2] = v + h * ax[i]
        st[i, 3] = w + h * ae[i]


@njit(cache=True, nogil=True)
def merson_step(st: np.ndarray, u: np.ndarray, coef: np.ndarray, minv: np.ndarray, h: float):
    """One fixed Runge-Kutta-Merson step of ``st`` (C, 4) in place, control held."""
    nc = st.shape[0]
    y0 = st.copy()
    y = st.copy()
    f = np.zeros((5, nc, 4))
    ax = np.empty(nc)
    ae = np.empty(nc)
    fx = np.empty(nc)
    fe = np.empty(nc)
    _held_forces(st, u, coef, fx, fe)
    a, b = MERSON_A, MERSON_B
    for j in range(5):
        for i in range(nc):
            for c in range(4):
                acc = 0.0
                for k in range(j):
                    acc += a[j, k] * f[k, i, c]
                y[i, c] = y0[i, c] + h * acc
        _rigid_accelerations(y, fx, fe, coef, minv, 0.0, 0.0, ax, ae)
        for i in range(nc):
            f[j, i, 0] = y[i, 2]
            f[j, i, 1] = y[i, 3]
            f[j, i, 2] = ax[i]
            f[j, i, 3] = ae[i]
    for i in range(nc):
        for c in range(4):
            acc = 0.0
            for k in range(5):
                acc += b[k] * f[k, i, c]
            st[i, c] = y0[i, c] + h * acc
