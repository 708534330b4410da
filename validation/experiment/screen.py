"""Screen geometry of the experiment (paper section 4.1, Fig. 11(b)).

The screen area is 1200 x 600 pixels; the model displacement range [-3, 3]
maps linearly to the horizontal pixels [1, 1200] (pixel 1 <-> -3, pixel 1200
<-> +3), so one pixel is 6/1199 = 5.004e-3 model units.  Lines are vertical
(overhead view): thick lines are the upper ends, thin lines the lower ends.
"""

from __future__ import annotations

import numpy as np

WIDTH_PX = 1200
HEIGHT_PX = 600
#: visible range of model displacements; a line outside it ends the trial
VISIBLE = 3.0
#: model units per pixel
UNIT_PER_PX = 2 * VISIBLE / (WIDTH_PX - 1)


def to_pixel(x: float | np.ndarray) -> float | np.ndarray:
    """Horizontal pixel (1 .. 1200, fractional) of model displacement ``x`` (-3 .. 3)."""
    return 1.0 + (np.asarray(x, dtype=float) + VISIBLE) / UNIT_PER_PX


def to_model(px: float | np.ndarray) -> float | np.ndarray:
    """Model displacement of horizontal pixel ``px`` (inverse of :func:`to_pixel`)."""
    return -VISIBLE + (np.asarray(px, dtype=float) - 1.0) * UNIT_PER_PX


def visible(x: np.ndarray) -> bool:
    """True when every displacement in ``x`` lies in the visible range [-3, 3]."""
    x = np.asarray(x, dtype=float)
    return bool(np.all(np.isfinite(x)) and np.all(np.abs(x) <= VISIBLE))
