"""Versions of the software a result was computed with (recorded in every result file)."""

from __future__ import annotations

import platform


def package_versions() -> dict[str, str]:
    """Versions of Python, the numerical stack, MuJoCo and cipval itself (matplotlib's
    from its installed metadata: importing it takes longer than a short run's stages)."""
    from importlib.metadata import PackageNotFoundError, version

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
            "matplotlib": version("matplotlib"), "cipval": cipval}  # fmt: skip
