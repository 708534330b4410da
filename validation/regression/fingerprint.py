"""What decides a run's round-off: the numerics fingerprint recorded in every results file.

With the same seeds, two runs give bit-identical numbers when the same code
runs the same floating-point operations in the same order.  What can change
that is (a) the versions of the packages that compute (numpy, scipy, numba,
MuJoCo, Python, cipval), (b) the instruction set the code is compiled for or
dispatches to at run time: the CPU architecture and its SIMD/FMA flags (numba
compiles for the host CPU; numpy and OpenBLAS choose kernels by CPU feature),
(c) the build of numpy and its BLAS, (d) the kernels OpenBLAS picked at
start-up (:func:`blas_kernels`).  OpenBLAS chooses its kernels by the CPU's
family and model, not only its flags: on an AMD family-26 CPU (Zen 5) OpenBLAS
0.3.31 takes its Haswell kernels, on the machine that made the shipped baseline
(the same flags) its SkylakeX ones, and 10 of the quick profile's 933 numbers
moved by round-off (relative 1e-12 to 1e-9, and more for differences of nearly
equal numbers); ``OPENBLAS_CORETYPE=SkylakeX`` on the Zen 5 machine reproduced all
933.  The kernel's build string (``platform.platform()``) changes none of these
and is not part of it.

The model files run (shipped or ``--mjcf``) are recorded by content digest:
a baseline made from other model files is not a regression reference for this
run (:func:`validation.regression.baseline.choose_mode`).
"""

from __future__ import annotations

import hashlib
import platform
from functools import cache
from pathlib import Path
from typing import Any

__all__ = ["NUMERIC_FLAGS", "blas_kernels", "cpu_flags", "model_digests", "numerics_fingerprint"]

#: CPU flags that change which floating-point kernels run (x86 SIMD and FMA, Arm
#: NEON/SVE); other flags (virtualisation, security mitigations) do not.
NUMERIC_FLAGS = frozenset(
    {
        "sse2",
        "sse3",
        "ssse3",
        "sse4_1",
        "sse4_2",
        "avx",
        "avx2",
        "fma",
        "f16c",
        "avx512f",
        "avx512dq",
        "avx512cd",
        "avx512bw",
        "avx512vl",
        "avx512ifma",
        "avx512vbmi",
        "avx512_vnni",
        "avx512_bf16",
        "avx512_fp16",
        "amx_tile",
        "asimd",
        "neon",
        "sve",
        "sve2",
        "fphp",
        "asimdhp",
    }
)


@cache
def cpu_flags() -> tuple[str, ...]:
    """The host CPU's numeric instruction-set flags (from /proc/cpuinfo; empty elsewhere)."""
    try:
        text = Path("/proc/cpuinfo").read_text()
    except OSError:
        return ()
    for line in text.splitlines():
        key, _, value = line.partition(":")
        if key.strip() in ("flags", "Features"):
            return tuple(sorted(set(value.split()) & NUMERIC_FLAGS))
    return ()


def _numpy_build() -> dict[str, Any]:
    import numpy as np

    try:
        cfg = np.show_config(mode="dicts")
    except TypeError:  # numpy < 1.26 has no mode
        return {"numpy": np.__version__}
    blas = cfg.get("Build Dependencies", {}).get("blas", {})
    simd = cfg.get("SIMD Extensions", {})
    return {
        "blas": f"{blas.get('name', '?')} {blas.get('version', '?')}",
        "simd_baseline": list(simd.get("baseline", [])),
        "simd_found": list(simd.get("found", [])),
    }


def blas_kernels() -> list[str]:
    """The BLAS libraries loaded by numpy and SciPy, each as "library version kernels"
    (threadpoolctl's ``internal_api``, ``version`` and ``architecture``: the kernel set
    OpenBLAS chose for this CPU at start-up, e.g. ``openblas 0.3.31.188.0 SkylakeX``),
    sorted, without repeats."""
    import numpy  # noqa: F401  (loads numpy's BLAS)
    import scipy.linalg  # noqa: F401  (loads SciPy's)
    from threadpoolctl import threadpool_info

    return sorted({f"{i.get('internal_api', '?')} {i.get('version', '?')} "
                   f"{i.get('architecture', '?')}"
                   for i in threadpool_info() if i.get("user_api") == "blas"})  # fmt: skip


def model_digests(model_files: dict[str, str] | None = None) -> dict[str, str]:
    """sha256 (first 16 hex digits) of each model run: the user's ``--mjcf`` file, else
    the MJCF the suite generates at the default parameters (:func:`cip.model.mjcf`)."""
    from cip.model import mjcf
    from cipcore.models import MODEL_NAMES

    out = {}
    for name in MODEL_NAMES:
        path = (model_files or {}).get(name)
        try:
            data = Path(path).read_bytes() if path else mjcf(name).encode()
        except OSError:
            out[name] = "unreadable"
            continue
        out[name] = hashlib.sha256(data).hexdigest()[:16]
    return out


def numerics_fingerprint(model_files: dict[str, str] | None = None) -> dict[str, Any]:
    """Everything that decides round-off (module docstring), and the model files' digests."""
    from validation.regression.versions import package_versions

    return {
        "versions": package_versions(),
        "machine": platform.machine(),
        "cpu_flags": list(cpu_flags()),
        "numpy_build": _numpy_build(),
        "blas_kernels": blas_kernels(),
        "model_digests": model_digests(model_files),
    }
