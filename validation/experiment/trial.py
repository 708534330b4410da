"""One trial, frame by frame: mouse pixels in, samples out, end rules (paper section 4.1).

Frame k happens at model time t_k = k * frame:

1. each subject's latest mouse pixel gives the lower end.  The first pixel a
   subject sends anchors the lower end at its initial position (paper:
   x_M(0) = -0.6, q_M1(0) = -0.6, q_M2(0) = 0.6); afterwards the lower end
   moves by one pixel = 6/1199 model units per pixel of mouse motion (the
   screen scale of :mod:`.screen`).  A subject who has not moved stays put.
2. The sample of frame k is taken: time, every line's position and velocity,
   the raw pixels and the frame's timing jitter.  The lower end's velocity
   is the backward difference over one frame (0 at k = 0, paper: all initial
   velocities 0).
3. End rules: any line (thick or thin, screen coordinates) outside [-3, 3]
   ends the trial ("out_of_range"); t_k = duration ends it ("time").
   "abort" and "disconnect" come from outside via :meth:`Trial.end`.
4. Otherwise the task model advances to t_{k+1} with these lower ends held.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from validation.experiment.screen import UNIT_PER_PX, VISIBLE
from validation.experiment.task import TaskModel, TaskSettings

END_REASONS = ("time", "out_of_range", "abort", "disconnect", "server_stop")


@dataclass
class Sample:
    """One 20 ms sample.  Positions in model coordinates (each stick's own reference),
    units of the screen's model range; velocities in units/s; time and jitter in s."""

    k: int
    t: float
    wall: float
    jitter: float
    tip_position: list[float]
    tip_velocity: list[float]
    base_position: list[float]
    base_velocity: list[float]
    pixel: list[float | None]

    def as_dict(self) -> dict:
        return self.__dict__.copy()


class Trial:
    """The frame logic of one trial (module docstring)."""

    def __init__(self, settings: TaskSettings, task: TaskModel) -> None:
        self.settings = settings
        self.task = task
        self.k = 0
        self.bases = settings.initial_bases()
        self._anchor: list[float | None] = [None] * settings.n_sticks
        self.end_reason: str | None = None
        self.end_detail: str = ""
        self.end_time: float | None = None

    @property
    def ended(self) -> bool:
        return self.end_reason is not None

    def end(self, reason: str, detail: str = "") -> None:
        """End the trial (first reason wins)."""
        if self.end_reason is None:
            self.end_reason = reason
            self.end_detail = detail
            self.end_time = self.k * self.settings.frame

    def screen_positions(self) -> tuple[np.ndarray, np.ndarray]:
        """(thick lines, thin lines) in screen model units (offsets added)."""
        off = self.settings.offsets
        return self.task.tips()[0] + off, self.bases + off

    def frame(
        self, pixels: list[float | None], jitter: float = 0.0, wall: float = math.nan
    ) -> Sample:
        """Run frame ``self.k`` with the subjects' latest pixels; returns its sample."""
        if self.ended:
            raise RuntimeError("the trial has ended")
        s = self.settings
        init = s.initial_bases()
        new = self.bases.copy()
        for i, px in enumerate(pixels):
            if px is None:
                continue
            if self._anchor[i] is None:
                self._anchor[i] = px
            new[i] = init[i] + (px - self._anchor[i]) * UNIT_PER_PX
        vel = (new - self.bases) / s.frame if self.k > 0 else np.zeros_like(new)
        self.bases = new
        n = s.n_sticks
        tip, tip_v = self.task.tips()
        sample = Sample(
            k=self.k, t=self.k * s.frame, wall=wall, jitter=jitter,
            tip_position=tip.tolist(), tip_velocity=tip_v.tolist(),
            base_position=new.tolist(), base_velocity=vel.tolist(),
            pixel=[None if p is None else float(p) for p in pixels],
        )  # fmt: skip
        tips, thins = self.screen_positions()
        lines = np.concatenate([tips, thins])
        if not (np.all(np.isfinite(lines)) and np.all(np.abs(lines) <= VISIBLE)):
            worst = int(np.argmax(np.abs(lines)))
            name = ("thick" if worst < n else "thin") + f" line {worst % n + 1}"
            self.end("out_of_range", f"{name} at {lines[worst]:.3f}")
        elif self.k >= s.n_frames:
            self.end("time")
        else:
            self.task.advance(new)
        self.k += 1 if not self.ended else 0
        return sample
