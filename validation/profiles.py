"""Run profiles of ``cip-validate run``: how many realisations, how long.

``quick`` (the default) exercises every check in a few minutes on two cores;
``paper`` uses the paper's realisation counts and durations (100 or 500
realisations over [0, 1200] s) where the paper states them, and a small grid of
the estimator choices the paper leaves unstated; ``robustness`` is ``paper``
with the full grid of those choices (validation.paper.claims.robustness).
"""

from __future__ import annotations

import zlib
from dataclasses import asdict, dataclass, field, replace

import numpy as np

#: The paper's gains for lambda1 = 5e-4 (Fig. 4 caption).
PAPER_BETA = {"single": 20.306, "coupled": 21.032}

#: Window (s) of the trajectory comparison: agreement to < 1 % over 10 s.
TRAJECTORY_WINDOW = 10.0


@dataclass(frozen=True)
class Profile:
    name: str
    seed: int = 2011
    # lambda1 of both engines at a few gains (agreement)
    lyapunov_gains: dict = field(
        default_factory=lambda: {"single": (19.5, 20.3, 23.0), "coupled": (20.5, 21.0, 23.0)}
    )
    lyapunov_duration: float = 200.0
    lyapunov_realizations: int = 8
    # m: the Benettin deviation's size (cip.lyapunov.lyapunov_full) for a float64 engine
    # and for one whose state is float32 (Capabilities.precision, Profile.lyapunov_epsilon):
    # agreement.FLOAT32_EPSILON_RULE
    benettin_epsilon: float = 1e-7
    benettin_epsilon_float32: float = 5e-4
    lyapunov_curve_gains: tuple = tuple(np.round(np.linspace(19.0, 24.0, 11), 3))
    # time series of both engines at the paper gains (agreement)
    # m: initial balancing error; near threshold the single balancer grows ~1e4-fold in
    # bursts over 200 s, so 1e-8 keeps every profile's series deep in the linear regime
    amplitude: float = 1e-8
    # m: the series' initial balancing error for an engine whose state is float32
    # (Capabilities.precision, Profile.series_amplitude): agreement.FLOAT32_AMPLITUDE_RULE
    amplitude_float32: float = 1e-5
    series_duration: float = 100.0
    series_realizations: int = 8
    # multifidelity agreement (validation.checks.multifidelity): the engine's series and
    # lambda1 on this many realisations, its twin and the reduced model on
    # mf_twin_realizations (same noise, nested); 0: off, every model on
    # series_realizations and lyapunov_realizations (quick: on, 3 and 16)
    mf_engine_realizations: int = 3
    mf_twin_realizations: int = 16
    # s: the lambda1 check's engine realisations, and the twin's paired with them, run
    # this long; the twin's and the reduced model's m realisations lyapunov_duration.
    # The paired difference engine - twin does not depend on it beyond 1e-4 1/s, 1/100
    # of the check's interval (docs/performance.md); 0: lyapunov_duration (quick: 50 s)
    mf_engine_duration: float = 50.0
    decimate: int = 5  # record every 5 ms
    spectrum_segment: float = 10.0  # s
    spectrum_band: tuple = (0.1, 20.0)  # Hz
    stcc_window: float = 5.0  # s (paper: Dt = 5)
    stcc_max_lag: float = 0.3  # s
    stcc_stride: float = 0.25  # s
    # amplitude scan (where agreement breaks down)
    scan_amplitudes: tuple = (1e-5, 1e-4, 1e-3, 1e-2, 3e-2, 1e-1, 2e-1, 3e-1)
    scan_duration: float = 10.0  # = the trajectory window: angle and verdicts over one span
    scan_realizations: int = 6
    # paper reproduction (reduced model, as in the paper)
    beta_star_duration: float = 1000.0
    beta_star_realizations: int = 16
    beta_star_gains: int = 5
    rms_duration: float = 600.0
    rms_realizations: int = 200
    rms_amplitude: float = 0.01
    peak_duration: float = 600.0
    peak_realizations: int = 16
    spectrum_duration: float = 1200.0
    spectrum_realizations: int = 8
    # estimator choices the paper leaves unstated (validation.paper.claims.robustness): the
    # fractions of the duration re-estimated (prefixes of the same simulations) and the grid; keys
    # missing from the grid take the paper table's defaults
    robustness_durations: tuple = (0.25, 0.5, 1.0)
    robustness_grid: dict = field(
        default_factory=lambda: {
            "window": (2.5, 5.0, 10.0),
            "max_lag": (0.2, 0.3),
            "dominance": (0.5, 0.8),
            "significance": ("bartlett",),
            "bins": (0.01,),
            "duration": (0.5, 1.0),
            "scale": ("median_std", "mad"),
            "normalise": (False, True),
            "half_width": (0.02, 0.1, 0.5),
            "segment": (10.0, 50.0),
            "fmax": (20.0,),
            "threshold": (0.001, 0.01, 0.1),
            "threshold_reference": ("rms", "median"),
        }
    )
    n_bootstrap: int = 500
    # the nonlinear stick, eq. (1), beside the linear single model
    nonlinear_realizations: int = 8
    nonlinear_duration: float = 600.0
    nonlinear_floors: tuple = (0.0, 1e-3)
    # rod-length study (validation/studies/rod_length.toml, these settings override it)
    #: s of the two clips the report embeds (a coupled MuJoCo run inside and one leaving
    #: the small-angle regime, initial errors clip_amplitudes in m); 0: no clips
    clip_duration: float = 6.0
    clip_amplitudes: tuple = (1e-3, 0.1)
    rod_study: dict = field(
        default_factory=lambda: {
            "realizations": 6,
            "duration": 20.0,
            "grid": {"rod_length_ratio": [0.1, 0.2, 0.5, 1.0, 2.0, 5.0], "amplitude": [0.001, 0.1]},
        }
    )

    def as_dict(self) -> dict:
        return asdict(self)

    def series_amplitude(self, precision: str) -> float:
        """The time series' initial balancing error (m) for an engine whose state has
        ``precision`` (``Capabilities.precision``: "float64" or "float32")."""
        return _by_precision({"float64": self.amplitude, "float32": self.amplitude_float32},
                             precision)  # fmt: skip

    def lyapunov_epsilon(self, precision: str) -> float:
        """The Benettin deviation's size (m) of lambda1 for an engine whose state has
        ``precision`` (``Capabilities.precision``: "float64" or "float32")."""
        return _by_precision(
            {"float64": self.benettin_epsilon, "float32": self.benettin_epsilon_float32},
            precision,
        )

    def seed_for(self, *labels: object) -> int:
        """A seed derived from the profile's seed and a label (stable across runs)."""
        key = zlib.crc32("/".join(map(str, labels)).encode())
        return int(np.random.SeedSequence(self.seed, spawn_key=(key,)).generate_state(1)[0])


PROFILES = {
    "quick": Profile(name="quick"),
    "paper": Profile(
        name="paper",
        mf_engine_realizations=0,  # the paper's realisation counts, every model plainly
        lyapunov_duration=500.0,
        lyapunov_realizations=16,
        series_duration=200.0,
        series_realizations=16,
        amplitude_float32=3e-7,  # 16 x 200 s: twin slopes 4.3e-6 off at 1e-6 m in float64
        scan_duration=10.0,
        scan_realizations=16,
        beta_star_duration=2000.0,
        beta_star_realizations=32,
        beta_star_gains=7,
        rms_duration=1200.0,
        rms_realizations=500,
        peak_duration=1200.0,
        peak_realizations=100,
        spectrum_duration=1200.0,
        spectrum_realizations=32,
        n_bootstrap=1000,
        nonlinear_realizations=16,
        nonlinear_duration=1200.0,
        rod_study={},  # the shipped study as it is
    ),
    # a tiny profile for the test suite: every code path, seconds
    "smoke": Profile(
        name="smoke",
        mf_engine_realizations=0,  # 3 realisations: nothing left to save
        mf_engine_duration=0.0,
        clip_duration=0.0,
        lyapunov_gains={"single": (19.5, 23.0), "coupled": (20.5, 23.0)},
        lyapunov_duration=20.0,
        lyapunov_realizations=3,
        lyapunov_curve_gains=(19.0, 21.0, 23.0),
        series_duration=45.0,
        series_realizations=3,
        amplitude_float32=1e-4,  # 3 x 45 s: twin slopes 2.2e-6, 4.5e-6 off at 3e-4 m in float64
        scan_amplitudes=(1e-5, 1e-3, 3e-1),
        scan_duration=10.0,
        scan_realizations=3,
        spectrum_segment=5.0,
        beta_star_duration=400.0,
        beta_star_realizations=8,
        beta_star_gains=4,
        rms_duration=40.0,
        rms_realizations=8,
        peak_duration=40.0,
        peak_realizations=3,
        spectrum_duration=60.0,
        spectrum_realizations=3,
        robustness_grid={
            "window": (2.5, 5.0),
            "dominance": (0.5, 0.8),
            "half_width": (0.1, 0.5),
            "segment": (5.0,),
            "threshold": (0.01, 0.1),
        },
        n_bootstrap=100,
        nonlinear_realizations=2,
        nonlinear_duration=40.0,
        rod_study={
            "realizations": 3,
            "duration": 8.0,
            "grid": {"rod_length_ratio": [0.2, 2.0], "amplitude": [0.001, 0.1]},
        },
    ),
}
#: The full grid of estimator choices on the paper's run sizes (``--profile robustness``).
PROFILES["robustness"] = replace(
    PROFILES["paper"],
    name="robustness",
    robustness_durations=(0.25, 0.5, 1.0),
    robustness_grid={
        "window": (2.5, 5.0, 10.0),
        "max_lag": (0.2, 0.3, 0.5),
        "dominance": (0.5, 0.6, 0.7, 0.8, 0.9),
        "significance": ("bartlett", "none"),
        "bins": (0.005, 0.01, 0.02),
        "duration": (0.25, 0.5, 1.0),
        "scale": ("median_std", "mad"),
        "normalise": (False, True),
        "half_width": (0.02, 0.05, 0.1, 0.25, 0.5),
        "segment": (10.0, 20.0, 50.0, 100.0),
        "fmax": (10.0, 20.0),
        "threshold": (0.001, 0.01, 0.1),
        "threshold_reference": ("rms", "median"),
    },
)


def _by_precision(values: dict[str, float], precision: str) -> float:
    """``values[precision]``; a ValueError naming the precisions allowed otherwise."""
    if precision not in values:
        raise ValueError(f"precision must be one of {sorted(values)}, got {precision!r}")
    return values[precision]
