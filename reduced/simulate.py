"""Time series of the reduced balancing models (paper eqs. bormann04:TM, sss08:TM).

    single:   x_T'' + gamma x_T' = alpha e(t),         x_M'' + gamma x_M' = beta R(t) e(t - tau)
    coupled:  2 q_T'' + 2 gamma q_T' = alpha (e_1 + e_2),
              q_Mi'' + gamma q_Mi' = beta R_i(t) e_i(t - tau),       e_i = q_T - q_Mi

Initial condition: bases at rest at 0, tip at rest at ``amplitude``, so every
balancing error starts at ``amplitude`` (m) with the constant history
e_i(t) = amplitude for t in [-tau, 0].
"""

from __future__ import annotations

import numpy as np

from . import _kernels
from ._driver import run_blocks
from .noise import ArrayNoise, GainNoise
from .params import (
    MODELS,
    STEPPERS,
    BalanceParams,
    ParameterError,
    check_choice,
    check_count,
    whole_steps,
)
from .schema import COMMON_FIELDS, Trajectory

#: Memory cap for the recorded arrays; raise it explicitly with ``max_bytes``.
DEFAULT_MAX_BYTES = 2 * 1024**3


def n_controllers(model: str) -> int:
    """1 for the single model, 2 for the coupled one."""
    return {"single": 1, "coupled": 2}[check_choice("model", model, MODELS)]


def check_amplitude(amplitude: float) -> float:
    a = float(amplitude)
    if not np.isfinite(a):
        raise ParameterError(f"amplitude must be a finite number (m), got {amplitude!r}")
    return a


def plan_recording(
    n_steps: int,
    n_realizations: int,
    nc: int,
    decimate: int,
    fields: tuple[str, ...],
    dtype: np.dtype,
    max_bytes: int,
    allowed: tuple[str, ...] = COMMON_FIELDS,
) -> int:
    """Check the recording request and return the number of samples."""
    decimate = check_count("decimate", decimate)
    for f in fields:
        if f not in allowed:
            raise ParameterError(f"fields: unknown field {f!r}; allowed: {', '.join(allowed)}")
    n_samples = -(-n_steps // decimate)
    need = n_samples * n_realizations * nc * len(fields) * np.dtype(dtype).itemsize
    if need > max_bytes:
        raise ParameterError(
            f"recording {len(fields)} field(s) x {n_realizations} realisations x {n_samples} "
            f"samples needs {need / 2**30:.2f} GiB > max_bytes {max_bytes / 2**30:.2f} GiB; "
            "raise decimate, record fewer fields, use dtype=float32 or raise max_bytes"
        )
    return n_samples


def simulate(
    model: str,
    params: BalanceParams,
    duration: float,
    n_realizations: int = 1,
    seed: int = 0,
    *,
    amplitude: float = 0.01,
    stepper: str = "semi-implicit",
    decimate: int = 1,
    fields: tuple[str, ...] = COMMON_FIELDS,
    dtype: type | np.dtype = np.float64,
    noise: GainNoise | None = None,
    threads: int | None = None,
    max_bytes: int = DEFAULT_MAX_BYTES,
    progress: bool = False,
) -> Trajectory:
    """Simulate the reduced model and record its time series.

    Parameters
    ----------
    model : "single" or "coupled".
    params : gains, damping, noise, delay and time step.
    duration : simulated time in s, a whole number of steps.
    n_realizations : independent noise realisations.
    seed : root seed of the noise (ignored when ``noise`` is given).
    amplitude : initial balancing error in m (see the module docstring).
    stepper : "semi-implicit" (MuJoCo ``Euler``) or "explicit" (Euler–Maruyama).
    decimate : record every ``decimate``-th step.
    fields : names from :data:`reduced.schema.COMMON_FIELDS` to record.
    dtype : dtype of the recorded arrays (float32 halves memory).
    noise : a :class:`GainNoise` to consume (e.g. shared with another engine);
        it must be at position 0.
    threads : worker threads (default: all cores); results do not depend on it.
    max_bytes : refuse recordings larger than this.

    Returns
    -------
    Trajectory with the requested fields shaped (R, S, C), S = ceil(steps / decimate).
    """
    nc = n_controllers(model)
    check_choice("stepper", stepper, STEPPERS)
    duration = _check_duration(duration)
    n_steps = whole_steps("duration", duration, params.dt)
    amplitude = check_amplitude(amplitude)
    noise = _noise(noise, seed, n_realizations, nc)
    nreal = noise.n_realizations
    n_samples = plan_recording(n_steps, nreal, nc, decimate, tuple(fields), dtype, max_bytes)

    d = params.delay_steps
    state = np.zeros((nreal, 2 + 2 * nc))
    state[:, 0] = amplitude
    hist = np.full((nreal, nc, d), amplitude)
    out = {f: np.empty((nreal, n_samples, nc), dtype=dtype) for f in fields}
    semi = stepper == "semi-implicit"

    def work(block: slice, xi: np.ndarray, n0: int) -> None:
        n = xi.shape[1]
        j0 = -(-n0 // decimate)
        j1 = -(-(n0 + n) // decimate)
        rec = np.empty((xi.shape[0], j1 - j0, nc, 4))
        # the ring-buffer slot of step n0 - d is n0 mod d in every realisation
        _kernels.advance_positions(
            xi, state[block], hist[block], n0 % d, params.alpha, params.beta,
            params.gamma, params.noise_scale, params.dt, semi, n0, decimate, rec,
        )  # fmt: skip
        _store(out, rec, block, j0, j1)

    run_blocks(noise, n_steps, work, threads=threads, progress=progress and "reduced")
    time = np.arange(n_samples) * (params.dt * decimate)
    attrs = {
        "engine": "reduced",
        "model": model,
        "stepper": stepper,
        "seed": noise.seed,
        "first_realization": noise.first_realization,
        "amplitude": amplitude,
        "duration": duration,
        "decimate": int(decimate),
        **params.as_dict(),
        "final_state": state.tolist() if nreal * state.shape[1] <= 4096 else None,
    }
    return Trajectory(time=time, data=out, attrs=attrs)


def _store(out: dict[str, np.ndarray], rec: np.ndarray, block: slice, j0: int, j1: int) -> None:
    """Copy recorded samples [tip pos, tip vel, base pos, base vel] into the schema's fields."""
    cols = {"tip_position": 0, "tip_velocity": 1, "base_position": 2, "base_velocity": 3}
    for name, arr in out.items():
        if name in cols:
            arr[block, j0:j1] = rec[..., cols[name]]
        elif name == "balancing_error":
            arr[block, j0:j1] = rec[..., 0] - rec[..., 2]
        elif name == "balancing_error_velocity":
            arr[block, j0:j1] = rec[..., 1] - rec[..., 3]


def _check_duration(duration: float) -> float:
    try:
        d = float(duration)
    except (TypeError, ValueError):
        raise ParameterError(
            f"duration must be a number of seconds > 0, got {duration!r}"
        ) from None
    if not np.isfinite(d) or d <= 0:
        raise ParameterError(f"duration must be finite and > 0 s, got {duration!r}")
    return d


def _noise(
    noise: GainNoise | ArrayNoise | None, seed: int, n_realizations: int, nc: int
) -> GainNoise:
    if noise is None:
        return GainNoise(seed, check_count("realizations", n_realizations), nc)
    if noise.n_controllers != nc:
        raise ParameterError(
            f"noise has {noise.n_controllers} controller stream(s), the model needs {nc}"
        )
    if noise.position != 0:
        raise ParameterError("noise must be at step 0 (call noise.reset())")
    return noise
