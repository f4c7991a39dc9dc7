"""Measured-loop features that laws use for their start values (guess)."""

from __future__ import annotations

import numpy as np


def loop_half_width(x: np.ndarray, force: np.ndarray, v: np.ndarray) -> float:
    """Half the mean vertical width (N) of a measured loop about its centreline.

    The centreline is the least-squares line F ≈ k·x + c0; the width is the mean residual
    while stretching (v < 0) minus that while contracting (v > 0), halved.  Positive for a
    physical loop (tension higher while stretching).
    """
    k, c0 = np.polyfit(x, force, 1)
    r = force - (k * x + c0)
    up, down = v > 0, v < 0
    if not (up.any() and down.any()):
        return 10.0
    return 0.5 * (float(np.mean(r[down])) - float(np.mean(r[up])))
