"""The reduced model as the registry's reference engine.

It answers the same :class:`cipcore.engine.Engine` calls as the rigid-body
engines (:func:`reduced.simulate.simulate`, :func:`reduced.lyapunov.lyapunov`,
and a chunk runner over the same compiled kernel), so that every engine is
validated against it by the same code.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from cipcore.engine import Capabilities, EngineMethods, check_options
from cipcore.models import BalanceModel
from cipcore.params import BalanceParams
from cipcore.results import LyapunovResult
from cipcore.scenario import Scenario, flat_options
from cipcore.schema import Trajectory, check_amplitude

from ._kernels import advance_positions
from .lyapunov import lyapunov
from .simulate import initial_positions, record_fields, simulate

#: The reduced kernel has no chunk limit of its own; the runner accepts this many steps.
MAX_CHUNK = 1 << 20


class ReducedChunks:
    """:class:`cipcore.engine.ChunkRunner` over the reduced kernel (semi-implicit stepper)."""

    def __init__(
        self, model: BalanceModel, params: BalanceParams, n_realizations: int, amplitude: float
    ) -> None:
        nc = model.n_controllers
        self.params = params
        self.n_realizations = n_realizations
        self.max_chunk = MAX_CHUNK
        self.step = 0
        self.d = params.delay_steps
        self.state, self.hist = initial_positions(n_realizations, nc, self.d, amplitude)

    def advance(self, xi: np.ndarray) -> dict[str, np.ndarray]:
        p, n = self.params, xi.shape[1]
        rec = np.empty((xi.shape[0], n, xi.shape[2], 4))
        advance_positions(
            np.ascontiguousarray(xi, dtype=float), self.state, self.hist, self.step % self.d,
            p.law, True, self.step, 1, rec,
        )  # fmt: skip
        self.step += n
        return record_fields(rec)


class ReducedEngine(EngineMethods):
    """The paper's reduced linear model (eqs. (3), (5)), float64 on the CPU."""

    name = "reduced"
    capabilities = Capabilities(rigid_body=False, family="reference", trajectory_tolerance=0.0)
    notes = "the paper's reduced linear model, numba kernel"

    #: the chunk runner class and the simulate function (the GPU engine swaps both)
    chunks: Any = ReducedChunks
    simulate_fn: Any = staticmethod(simulate)

    def unavailable(self) -> str | None:
        return None

    def make_runner(self, model: BalanceModel, params: BalanceParams, n_realizations: int,
                    amplitude: float, physical: Any) -> ReducedChunks:  # fmt: skip
        if physical is not None:
            check_options(self.name, "runner", {"physical": physical}, ())
        return self.chunks(model, params, n_realizations, check_amplitude(amplitude))

    def accepted(self, method: str) -> frozenset[str]:
        if method == "simulate":
            return flat_options(self.simulate_fn)
        return flat_options(lyapunov, ())

    def simulate_scenario(self, scenario: Scenario, grouped: dict[str, Any]) -> Trajectory:
        return self.simulate_fn(scenario, **grouped)

    def lyapunov_scenario(self, scenario: Scenario, grouped: dict[str, Any]) -> LyapunovResult:
        return lyapunov(scenario, **grouped)


ENGINE = ReducedEngine()
