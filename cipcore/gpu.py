"""Where the warp-based GPU engines run: a CUDA device, or warp's CPU device on request.

The GPU engines (``mujoco-warp``, ``reduced-gpu``) need ``warp-lang`` (and
``mujoco-warp``), installed by ``pip install 'cipval[warp]'``.  Without a CUDA
device they are unavailable, with the reason, unless the environment variable
``CIPVAL_WARP_DEVICE=cpu`` opts into warp's CPU device: the same kernels,
compiled for the CPU, slow, for tests and smoke runs.  Nothing here imports
warp until asked.
"""

from __future__ import annotations

import importlib.util
import os

from .params import ParameterError

#: Environment variable choosing the device: "cuda" (default) or "cpu" (warp's CPU device).
DEVICE_ENV = "CIPVAL_WARP_DEVICE"
DEVICES = ("cuda", "cpu")


def requested_device() -> str:
    """The device asked for through ``CIPVAL_WARP_DEVICE`` ("cuda" unless set to "cpu")."""
    dev = os.environ.get(DEVICE_ENV, "cuda").strip().lower() or "cuda"
    if dev not in DEVICES:
        raise ParameterError(f"{DEVICE_ENV} must be one of {', '.join(DEVICES)}, got {dev!r}")
    return dev


def warp_device() -> str:
    """The warp device name to run on: "cuda:0" or "cpu"."""
    return "cpu" if requested_device() == "cpu" else "cuda:0"


def declared_device() -> str:
    """The ``Capabilities.device`` of a warp engine here: "cpu" when opted into, else "gpu"."""
    try:
        return "cpu" if requested_device() == "cpu" else "gpu"
    except ParameterError:
        return "gpu"


def warp_unavailable(packages: tuple[str, ...] = ("warp",)) -> str | None:
    """None when warp (and ``packages``) can run on the requested device, else why not."""
    for mod in packages:
        if importlib.util.find_spec(mod) is None:
            return f"Python package {mod!r} is not installed (pip install 'cipval[warp]')"
    try:
        dev = requested_device()
    except ParameterError as exc:
        return str(exc)
    if dev == "cpu":
        return None
    import warp as wp

    wp.config.quiet = True
    if not wp.is_cuda_available():
        return (
            f"no CUDA device (warp sees only the CPU); set {DEVICE_ENV}=cpu to run "
            "on warp's CPU device (slow, for tests)"
        )
    return None
