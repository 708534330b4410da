"""The task model stepped on the server between 20 ms frames (paper section 4.1).

The subjects' mice replace the pseudo-neural controllers of the reduced model;
only the upper ends are computed.  Single task, eq. ((3)) with x_M
from the mouse::

    x_T'' + gamma x_T' = alpha (x_T - x_M)

Coupled task, eq. ((5)) with q_M1, q_M2 from two mice::

    2 q_T'' + 2 gamma q_T' = alpha (Dq_1 + Dq_2),     Dq_i = q_T - q_Mi,

i.e. q_T'' + gamma q_T' = alpha (q_T - (q_M1 + q_M2) / 2): the common tip is
driven by the mean of the two lower ends.

Reading of the rigid rod (paper eq. (4) and section 4.1).  In the reduced
model both tips share one coordinate q_T, measured from each stick's own
upright reference (as in :mod:`cipcore.schema`).  On the screen the two thick
lines are drawn a constant distance l apart, q_T1 = q_T and q_T2 = q_T + l,
and the second subject's thin line at q_M2 + l.  The paper defines
l := q_T1 - q_T2, but with l = 1 that would put the second tip at -1.5 and
make the initial errors Dq_1 = 0.1, Dq_2 = -2.1; with the second tip to the
right (q_T2 = q_T1 + l) the paper's initial screen positions q_T(0) = -0.5,
q_M1(0) = -0.6, q_M2(0) = 0.6 give the symmetric errors Dq_1 = 0.1 and
Dq_2 = -0.1, which is how we read it.  Screen positions are therefore the
model's plus a per-stick offset (0 and l).

Between frames the lower ends are held at their latest sampled value (zero-
order hold, the mouse is sampled at 50 Hz) and the tip is advanced with
sub-steps dt = 1 ms by semi-implicit Euler (velocity first, then position
with the new velocity), the stepper of the project's reduced model.  Because
the lower end is constant over a frame, the n = frame/dt sub-steps are one
linear map, applied exactly as the composed matrix.

Engines are listed in :data:`ENGINES`; the registry is the only place that
knows their names.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import Protocol

import numpy as np

from cipcore import BalanceParams, ParameterError
from cipcore.models import MODEL_NAMES, get_model
from cipcore.params import check_choice, check_positive, whole_steps

MODES = MODEL_NAMES
#: Paper section 4.1: alpha = beta = 21, gamma = 50, rod length l = 1.
EXPERIMENT = {"alpha": 21.0, "beta": 21.0, "gamma": 50.0, "rod_length": 1.0}
#: 50 Hz sampling of the mice and animation of the lines (s)
FRAME = 0.02
#: ten minutes (s)
DURATION = 600.0
#: Initial screen positions (paper section 4.1); all velocities 0.
INITIAL_TIP = -0.5
INITIAL_BASES = {"single": (-0.6,), "coupled": (-0.6, 0.6)}


def experiment_params(**changes: float) -> BalanceParams:
    """The experiment's BalanceParams: alpha = beta = 21, gamma = 50, paper nu, tau, dt = 1 ms."""
    base = {k: v for k, v in EXPERIMENT.items() if k != "rod_length"}
    return BalanceParams(**{**base, **changes})


@dataclass(frozen=True)
class TaskSettings:
    """Everything that fixes one trial's model.

    Attributes
    ----------
    mode : "single" or "coupled".
    params : alpha (1/s^2), gamma (1/s) and the sub-step dt (s) of the tip;
        beta, nu, tau are the defaults of bot subjects.
    rod_length : l, distance of the thick lines in the coupled task (model units).
    frame : sampling interval of the mice and of the recording (s).
    duration : the trial ends after this time (s).
    """

    mode: str = "single"
    params: BalanceParams = field(default_factory=experiment_params)
    rod_length: float = EXPERIMENT["rod_length"]
    frame: float = FRAME
    duration: float = DURATION

    def __post_init__(self) -> None:
        check_choice("mode", self.mode, MODES)
        check_positive("rod_length", self.rod_length, allow_zero=True)
        check_positive("frame", self.frame)
        whole_steps("frame", self.frame, self.params.dt)
        check_positive("trial duration", self.duration)
        if self.duration < self.frame:
            raise ParameterError(f"trial duration must be >= frame = {self.frame} s")

    @property
    def n_sticks(self) -> int:
        return get_model(self.mode).n_controllers

    @property
    def offsets(self) -> np.ndarray:
        """Screen offset of each stick (model units): 0, and l for the second stick."""
        return np.array([0.0, self.rod_length][: self.n_sticks])

    @property
    def n_frames(self) -> int:
        """Number of model steps of a full-length trial (samples are n_frames + 1)."""
        return round(self.duration / self.frame)

    @property
    def substeps(self) -> int:
        return whole_steps("frame", self.frame, self.params.dt)

    def initial_bases(self) -> np.ndarray:
        """Initial lower ends in model coordinates (screen minus offset)."""
        return np.array(INITIAL_BASES[self.mode]) - self.offsets

    def as_dict(self) -> dict:
        d = asdict(self)
        d["params"] = self.params.as_dict()
        d["initial_tip"] = INITIAL_TIP
        d["initial_bases_screen"] = list(INITIAL_BASES[self.mode])
        d["offsets"] = self.offsets.tolist()
        return d


class TaskModel(Protocol):
    """What the trial needs from an engine."""

    name: str

    def tips(self) -> tuple[np.ndarray, np.ndarray]:
        """Upper ends of the sticks now: positions and velocities, model coordinates, (C,)."""
        ...

    def advance(self, bases: np.ndarray) -> None:
        """Advance one frame with the lower ends (model coordinates) held at ``bases``."""
        ...


def semi_implicit_map(
    alpha: float, gamma: float, dt: float, n: int
) -> tuple[np.ndarray, np.ndarray]:
    """n semi-implicit Euler steps of y'' + gamma y' = alpha (y - m), m held, as y_n = P y_0 + G m.

    One step: v <- v + dt (-gamma v + alpha (y - m)); y <- y + dt v, i.e.
    (y, v) <- A (y, v) + B m with A = [[1 + alpha dt^2, dt (1 - gamma dt)],
    [alpha dt, 1 - gamma dt]] and B = [-alpha dt^2, -alpha dt].  Returns
    P = A^n (2 x 2) and G = sum_{j<n} A^j B (2,).
    """
    a = np.array([[1 + alpha * dt * dt, dt * (1 - gamma * dt)], [alpha * dt, 1 - gamma * dt]])
    b = np.array([-alpha * dt * dt, -alpha * dt])
    p = np.eye(2)
    g = np.zeros(2)
    for _ in range(n):
        g = a @ g + b
        p = a @ p
    return p, g


class ReducedTask:
    """Tip of the reduced model (module docstring), advanced frame by frame."""

    name = "reduced"

    def __init__(self, settings: TaskSettings) -> None:
        p = settings.params
        self._n = settings.n_sticks
        self._map, self._gain = semi_implicit_map(p.alpha, p.gamma, p.dt, settings.substeps)
        self._y = np.array([INITIAL_TIP, 0.0])

    def tips(self) -> tuple[np.ndarray, np.ndarray]:
        return np.full(self._n, self._y[0]), np.full(self._n, self._y[1])

    def advance(self, bases: np.ndarray) -> None:
        self._y = self._map @ self._y + self._gain * float(np.mean(bases))


class MujocoTask:
    """The rigid-body CIP of :mod:`cip.model` with the mouse driving each cart.

    The bodies are the project's MuJoCo model built from the experiment's
    parameters (:meth:`cip.model.CIPParams.from_reduced`: pendulum length
    L = g / alpha, damping gamma, point-mass bob with m/M = 1e-3, the rod of
    length l as a tendon equality; displacements in m = model units).  Each cart
    follows its subject's lower end through a stiff, critically damped position
    servo on its motor ``u_i``, force M (omega^2 (x_mouse - x_M) - 2 omega x_M'),
    omega = :attr:`SERVO_OMEGA` (lag 2/omega = 4 ms), recomputed every 1 ms
    sub-step of MuJoCo's ``Euler`` integrator.  The pendulum starts at the angle
    that puts its tip at the paper's initial position, at rest; the upper end
    reported is the bob, x_M + L sin(theta), and its velocity.  Unlike the reduced
    model the two tips of the coupled model are two bodies held together by a
    soft constraint, so each stick reports its own tip.
    """

    name = "mujoco"
    SERVO_OMEGA = 500.0

    def __init__(self, settings: TaskSettings) -> None:
        import mujoco

        from cip.model import CIPParams, build
        from cip.names import cart_joint, hinge_joint, motor

        phys = CIPParams.from_reduced(settings.params, rod_length=max(settings.rod_length, 1e-3))
        self._mj = mujoco
        self.model = build(settings.mode, phys)
        self.data = mujoco.MjData(self.model)
        self._n = settings.n_sticks
        self._L = phys.pendulum_length
        self._M = phys.cart_mass
        self._sub = settings.substeps
        obj = mujoco.mjtObj
        self._cart = [self.model.joint(cart_joint(i + 1)).qposadr[0] for i in range(self._n)]
        self._hinge = [self.model.joint(hinge_joint(i + 1)).qposadr[0] for i in range(self._n)]
        self._cart_v = [self.model.joint(cart_joint(i + 1)).dofadr[0] for i in range(self._n)]
        self._hinge_v = [self.model.joint(hinge_joint(i + 1)).dofadr[0] for i in range(self._n)]
        self._u = [mujoco.mj_name2id(self.model, obj.mjOBJ_ACTUATOR, motor(i + 1))
                   for i in range(self._n)]  # fmt: skip
        for i, b in enumerate(settings.initial_bases()):
            self.data.qpos[self._cart[i]] = b
            self.data.qpos[self._hinge[i]] = np.arcsin((INITIAL_TIP - b) / self._L)
        mujoco.mj_forward(self.model, self.data)

    def tips(self) -> tuple[np.ndarray, np.ndarray]:
        q, v = self.data.qpos, self.data.qvel
        th = q[self._hinge]
        pos = q[self._cart] + self._L * np.sin(th)
        vel = v[self._cart_v] + self._L * np.cos(th) * v[self._hinge_v]
        return pos, vel

    def advance(self, bases: np.ndarray) -> None:
        w = self.SERVO_OMEGA
        d = self.data
        for _ in range(self._sub):
            x, v = d.qpos[self._cart], d.qvel[self._cart_v]
            d.ctrl[self._u] = self._M * (w * w * (bases - x) - 2 * w * v)
            self._mj.mj_step(self.model, d)


#: engine name -> factory
ENGINES: dict[str, type] = {"reduced": ReducedTask, "mujoco": MujocoTask}


def make_task(engine: str, settings: TaskSettings) -> TaskModel:
    """The task model of ``engine`` (one of :data:`ENGINES`)."""
    check_choice("engine", engine, tuple(ENGINES))
    return ENGINES[engine](settings)
