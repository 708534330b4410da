"""The random feedback gain R_i(t) = 1 + nu*xi_i(t) as a shareable value.

Paper section 2: xi_i are mutually independent standard Gaussian white noises.
In a time-stepping integrator with step h the white noise is held constant over
each step and scaled by 1/sqrt(h) (Euler–Maruyama)::

    R_{i,k} = 1 + nu * xi_{i,k} / sqrt(h),      xi_{i,k} ~ N(0, 1) i.i.d.

Without the 1/sqrt(h) the noise would vanish as h -> 0.  Because the noise
multiplies a *delayed* state, Ito and Stratonovich readings coincide.

A :class:`GainNoise` is a value: a seed plus the shape of the draws.  It owns
one independent random stream per realisation (``SeedSequence(seed).spawn``),
so realisation ``r`` gets the same draws whatever the number of realisations,
threads or processes, and whatever the chunking of time.  The reduced model
(:mod:`reduced.simulate`) and the MuJoCo model (:mod:`cip.simulate`) both
consume the *same* draws for the same seed.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .params import ParameterError, check_count


class _NoiseSource:
    """What both noise sources share: whole chunks built from per-realisation ``fill``."""

    n_realizations: int
    n_controllers: int
    position: int
    seed: int
    first_realization: int

    def fill(self, realization: int, out: np.ndarray) -> None:
        raise NotImplementedError

    def stream(self, realization: int) -> tuple[int, int]:
        """(seed, index) of realisation ``realization``'s stream: what keys its other
        seeded draws (e.g. :func:`cipcore.seeds.tangent_deviation`)."""
        return self.seed, self.first_realization + realization

    def next_chunk(self, n_steps: int, out: np.ndarray | None = None) -> np.ndarray:
        """The next ``n_steps`` draws of every realisation, shape (R, n_steps, C)."""
        if out is None:
            out = np.empty((self.n_realizations, n_steps, self.n_controllers))
        for r in range(self.n_realizations):
            self.fill(r, out[r])
        self.position += n_steps
        return out


@dataclass
class GainNoise(_NoiseSource):
    """Standard-normal draws xi[r, k, i] for realisation r, step k, controller i.

    Parameters
    ----------
    seed : int
        Root seed; realisation ``r`` uses ``SeedSequence(seed).spawn(...)[r]``,
        i.e. ``SeedSequence(seed, spawn_key=(first_realization + r,))``.
    n_realizations : int
        Number of independent realisations.
    n_controllers : int
        1 for the single model, 2 for the coupled one.
    first_realization : int
        Index of the first realisation (lets a run be split across workers
        without changing any draw).

    Notes
    -----
    Draws are consumed in order by :meth:`next_chunk`; :meth:`reset` rewinds.
    For a realisation the draws for steps ``[0, n)`` equal those obtained in
    any chunking of ``[0, n)``.
    """

    seed: int
    n_realizations: int
    n_controllers: int
    first_realization: int = 0
    _rngs: list[np.random.Generator] = field(init=False, repr=False)
    position: int = field(init=False, default=0)

    def __post_init__(self) -> None:
        self.seed = check_count("seed", self.seed, minimum=0)
        self.n_realizations = check_count("realizations", self.n_realizations)
        self.n_controllers = check_count("n_controllers", self.n_controllers)
        self.first_realization = check_count("first_realization", self.first_realization, 0)
        self.reset()

    def reset(self) -> None:
        """Rewind every stream to step 0."""
        self._rngs = [
            np.random.Generator(
                np.random.PCG64(
                    np.random.SeedSequence(self.seed, spawn_key=(self.first_realization + r,))
                )
            )
            for r in range(self.n_realizations)
        ]
        self.position = 0

    def fill(self, realization: int, out: np.ndarray) -> None:
        """Draw the next ``out.shape[0]`` steps of one realisation into ``out``.

        ``out`` has shape (steps, n_controllers), float64, C-contiguous.  Used by
        threaded callers that advance each realisation's stream separately;
        releases the GIL while drawing.
        """
        self._rngs[realization].standard_normal(out=out)

    def draws(self, n_steps: int) -> np.ndarray:
        """All draws for steps [0, n_steps) from a fresh copy (does not advance ``self``)."""
        return GainNoise(
            self.seed, self.n_realizations, self.n_controllers, self.first_realization
        ).next_chunk(n_steps)


def random_gain(xi: np.ndarray, nu: float, dt: float) -> np.ndarray:
    """R = 1 + nu * xi / sqrt(dt): the held random gain over each step (dimensionless)."""
    return 1.0 + (nu / np.sqrt(dt)) * xi


class ArrayNoise(_NoiseSource):
    """Given draws xi (R, steps, C) served through the :class:`GainNoise` interface.

    For handing externally generated or hand-made noise (tests, identical
    streams for two controllers) to either engine.
    """

    def __init__(self, xi: np.ndarray, seed: int = 0, first_realization: int = 0) -> None:
        xi = np.asarray(xi, dtype=float)
        if xi.ndim != 3:
            raise ValueError(
                f"xi must have shape (realizations, steps, controllers), got {xi.shape}"
            )
        self.xi = xi
        self.seed = seed
        self.first_realization = first_realization
        self.n_realizations, self.n_steps, self.n_controllers = xi.shape
        self.position = 0
        self._pos = [0] * self.n_realizations

    def reset(self) -> None:
        self.position = 0
        self._pos = [0] * self.n_realizations

    def fill(self, realization: int, out: np.ndarray) -> None:
        p = self._pos[realization]
        n = out.shape[0]
        if p + n > self.n_steps:
            raise ValueError(f"ArrayNoise holds {self.n_steps} steps; asked for step {p + n}")
        out[...] = self.xi[realization, p : p + n]
        self._pos[realization] = p + n


class StackedNoise(_NoiseSource):
    """Several noise sources of the same controllers served as one batch of realisations.

    Realisation r of the stack is realisation r - offset of the part it falls in, with
    that part's draws and stream key (:meth:`stream`): a run of the stack gives each
    realisation the numbers it gets run alone.  What lets one engine call run several
    scenarios that differ only in their seed and gain (the lambda1 check's gains of a
    model: :func:`cip.lyapunov.lyapunov_full`'s ``betas``).
    """

    def __init__(self, parts: list[GainNoise | ArrayNoise]) -> None:
        if not parts:
            raise ParameterError("noise: a stack needs at least one part")
        nc = {p.n_controllers for p in parts}
        if len(nc) != 1:
            raise ParameterError(f"noise: the parts' controller counts differ: {sorted(nc)}")
        self.parts = list(parts)
        self.n_controllers = nc.pop()
        self.n_realizations = sum(p.n_realizations for p in parts)
        self._where = [(p, r) for p in parts for r in range(p.n_realizations)]
        self.position = 0

    def reset(self) -> None:
        """Rewind every part to step 0."""
        for p in self.parts:
            p.reset()
        self.position = 0

    def fill(self, realization: int, out: np.ndarray) -> None:
        part, r = self._where[realization]
        part.fill(r, out)

    def stream(self, realization: int) -> tuple[int, int]:
        part, r = self._where[realization]
        return part.stream(r)


def make_noise(
    noise: GainNoise | ArrayNoise | StackedNoise | None, seed: int, n_realizations: int, nc: int
) -> GainNoise | ArrayNoise | StackedNoise:
    """A fresh seeded :class:`GainNoise`, or ``noise`` checked for C streams at step 0."""
    if noise is None:
        return GainNoise(seed, check_count("realizations", n_realizations), nc)
    if noise.n_controllers != nc:
        raise ParameterError(
            f"noise has {noise.n_controllers} controller stream(s), the model needs {nc}"
        )
    if noise.position != 0:
        raise ParameterError("noise must be at step 0 (call noise.reset())")
    return noise
