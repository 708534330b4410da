"""Versions of the software a result was computed with (recorded in every result file)."""

from __future__ import annotations

import platform


def package_versions() -> dict[str, str]:
    """Versions of Python, the numerical stack, MuJoCo and cipval itself."""
    from importlib.metadata import PackageNotFoundError, version

    import matplotlib
    import mujoco
    import numba
    import numpy as np
    import scipy

    try:
        cipval = version("cipval")
    except PackageNotFoundError:
        cipval = "not installed"
    return {"python": platform.python_version(), "numpy": np.__version__,
            "scipy": scipy.__version__, "numba": numba.__version__, "mujoco": mujoco.__version__,
            "matplotlib": matplotlib.__version__, "cipval": cipval}  # fmt: skip
