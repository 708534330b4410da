"""Bot subjects: the pseudo-neural controller of eq. ((5)) taking a seat.

The bot watches the screen as a subject does: at frame k it sees its own
balancing error e_k = (thick line) - (thin line) as displayed, held until the
next frame.  Its hand, the lower end, obeys the controller equation of the
reduced model (paper eqs. (3), (5))::

    x_M'' + gamma x_M' = beta R(t) e_screen(t - tau),   R = 1 + nu xi(t),

integrated with sub-steps dt (semi-implicit Euler, noise held over a
sub-step and scaled by 1/sqrt(dt) as in :mod:`cipcore.noise`); before the
first frame the history is e_0.  Having seen frame k it moves its hand to
t_{k+1} and reports the hand's (fractional) pixel as its mouse sample for
frame k+1, so its total latency is tau plus the one-frame sampling of the
screen, like a subject's neural delay plus the computer's.  ``nu = 0`` is the
noise-free bot.  A seed fixes every draw.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from cipcore import BalanceParams, ParameterError, random_gain
from cipcore.params import check_count, whole_steps
from validation.experiment.screen import to_pixel


@dataclass(frozen=True)
class BotSpec:
    """A bot's settings: gain beta (1/s^2), delay tau (s), noise nu (s^1/2), seed."""

    beta: float
    tau: float
    nu: float
    seed: int = 0

    def __post_init__(self) -> None:
        check_count("bot seed", self.seed, minimum=0)

    def as_dict(self) -> dict:
        return {"kind": "bot", **asdict(self)}


class PseudoNeuralBot:
    """One bot seat (module docstring).

    Parameters
    ----------
    spec : gain, delay, noise and seed.
    params : the task's parameters (gamma and the sub-step dt are used).
    frame : frame interval (s); ``tau`` must be a whole number of sub-steps.
    base0 : initial screen position of the hand (model units).
    """

    def __init__(self, spec: BotSpec, params: BalanceParams, frame: float, base0: float) -> None:
        self.p = params.with_(beta=spec.beta, tau=spec.tau, nu=spec.nu)  # validates
        self.spec = spec
        self.n_sub = whole_steps("frame", frame, self.p.dt)
        self.d = self.p.delay_steps
        if self.d < 1:
            raise ParameterError(f"bot tau must be >= dt = {self.p.dt} s")
        self.x = float(base0)
        self.v = 0.0
        self.seen: list[float] = []
        self.rng = np.random.Generator(np.random.PCG64(np.random.SeedSequence(spec.seed)))

    def initial_pixel(self) -> float:
        return float(to_pixel(self.x))

    def respond(self, k: int, error: float) -> float:
        """See frame ``k``'s error (model units); return the pixel for frame k + 1."""
        if k != len(self.seen):
            raise ValueError(f"bot expected frame {len(self.seen)}, got {k}")
        self.seen.append(float(error))
        p = self.p
        gain = random_gain(self.rng.standard_normal(self.n_sub), p.nu, p.dt)
        x, v = self.x, self.v
        for n in range(self.n_sub):
            j = (k * self.n_sub + n - self.d) // self.n_sub  # frame shown at t - tau
            e = self.seen[max(j, 0)]
            v += p.dt * (-p.gamma * v + p.beta * gain[n] * e)
            x += p.dt * v
        self.x, self.v = x, v
        return float(to_pixel(x))
