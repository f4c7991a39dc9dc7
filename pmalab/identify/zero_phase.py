"""A zero-phase 2nd-order Butterworth low-pass (forward and backward: 4th order, no lag).

Written out here instead of importing ``scipy.signal`` (whose package import alone costs
more than a whole ``pmalab identify`` of a campaign should): the biquad from the bilinear
transform with frequency pre-warping, run in direct form II transposed, with the
steady-state initial conditions and odd-extension padding of ``scipy.signal.sosfiltfilt``
(``padtype="odd"``).  The tests check it against SciPy to round-off.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit


def butter2(wn: float) -> tuple[np.ndarray, np.ndarray]:
    """(b, a) of the 2nd-order Butterworth low-pass, ``wn`` = cut-off / Nyquist ∈ (0, 1)."""
    k = math.tan(math.pi * wn / 2.0)  # pre-warped analogue cut-off
    norm = 1.0 / (1.0 + math.sqrt(2.0) * k + k * k)
    b0 = k * k * norm
    b = np.array([b0, 2.0 * b0, b0])
    a = np.array([1.0, 2.0 * (k * k - 1.0) * norm, (1.0 - math.sqrt(2.0) * k + k * k) * norm])
    return b, a


def _zi(b: np.ndarray, a: np.ndarray) -> np.ndarray:
    """Steady-state DF2T state for a unit step input (``scipy.signal.lfilter_zi``)."""
    i_minus_a = np.array([[1.0 + a[1], -1.0], [a[2], 1.0]])
    return np.linalg.solve(i_minus_a, b[1:] - a[1:] * b[0])


@njit(cache=True, fastmath=False)
def _biquad(b, a, x, z0, z1):
    y = np.empty_like(x)
    for i in range(x.shape[0]):
        xi = x[i]
        yi = b[0] * xi + z0
        z0 = b[1] * xi - a[1] * yi + z1
        z1 = b[2] * xi - a[2] * yi
        y[i] = yi
    return y


def filtfilt2(b: np.ndarray, a: np.ndarray, y: np.ndarray, padlen: int) -> np.ndarray:
    """Forward-backward biquad with odd-extension padding of ``padlen`` samples each end."""
    y = np.asarray(y, dtype=np.float64)
    if padlen > 0:
        left = 2.0 * y[0] - y[padlen:0:-1]
        right = 2.0 * y[-1] - y[-2 : -(padlen + 2) : -1]
        ext = np.concatenate([left, y, right])
    else:
        ext = y
    zi = _zi(b, a)
    fwd = _biquad(b, a, ext, zi[0] * ext[0], zi[1] * ext[0])
    rev = fwd[::-1].copy()
    back = _biquad(b, a, rev, zi[0] * rev[0], zi[1] * rev[0])[::-1]
    return back[padlen : back.shape[0] - padlen] if padlen > 0 else back


def load_compiled() -> None:
    """Load the compiled filter now (numba's CPU target with it: its first load of
    compiled code costs ~0.1 s), by filtering a few samples of the types a run's samples
    have (float64, contiguous), so the cached machine code is loaded, never another
    compiled."""
    b, a = butter2(0.2)
    filtfilt2(b, a, np.zeros(32), 6)
