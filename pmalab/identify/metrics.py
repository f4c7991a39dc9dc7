"""Validation metrics of a force prediction against a measurement.

Definitions (docs/reference/json.md; MATLAB ``compare`` and the nonlinear-identification benchmarks):

* ``rmse``  — RMS of (predicted − measured) force, N;
* ``nrmse`` — rmse / standard deviation of the measured force (0 = perfect, 1 = no better
  than the mean);
* ``fit_percent`` = 100·(1 − nrmse);
* ``max_error`` — largest |predicted − measured|, N;
* ``energy_error_percent`` — signed error of the energy dissipated per cycle,
  100·(E_model − E_measured)/E_measured, where E = −∮F dx is the loop area (N·mm = mJ;
  positive for a physical loop: tension is higher while the muscle is stretched, x falling);
  positive means the model dissipates too much;
* ``branch_rmse`` — rmse on the ``stretch`` branch (x decreasing: the cylinder pulls the
  muscle longer) and on the ``release`` branch (x increasing: the muscle contracts).

``x`` should be the noise-robust (zero-phase filtered) drive position in mm; the branch of
each sample is the sign of its smoothed velocity.
"""

from __future__ import annotations

import itertools
import math

import numpy as np


def moving_mean(x: np.ndarray, w: int) -> np.ndarray:
    """Centred moving mean over ``w`` samples, ends padded with the edge values
    (``scipy.ndimage.uniform_filter1d(x, w, mode="nearest")``)."""
    lo, hi = w // 2, w - 1 - w // 2
    xp = np.concatenate([np.full(lo, x[0]), x, np.full(hi, x[-1])])
    c = np.concatenate([[0.0], np.cumsum(xp)])
    return (c[w:] - c[:-w]) / w


def _cycle_samples(x: np.ndarray) -> float:
    """Samples per cycle of a cycling position, from its swings across the middle of its
    range (a Schmitt trigger at ±25 % of the range, so noise at a crossing counts once);
    the record's length when it swings less than once."""
    lo, hi = np.percentile(x, [5, 95])
    mid, band = 0.5 * (lo + hi), 0.25 * (hi - lo)
    state = np.where(x > mid + band, 1, np.where(x < mid - band, -1, 0))
    s = state[state != 0]
    swings = int(np.count_nonzero(np.diff(s))) if s.size > 1 else 0
    return x.shape[0] / (swings / 2.0) if swings >= 2 else float(x.shape[0])


def branch_masks(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Boolean masks (stretch, release): x decreasing / x increasing.

    The direction is read from a moving mean of the position (n/400 samples wide), never
    wider than a twentieth of a cycle (a record of hundreds of cycles would otherwise be
    smoothed flat)."""
    x = np.asarray(x, dtype=np.float64)
    w = max(1, x.shape[0] // 400)
    if w > 1:
        w = max(1, min(w, int(_cycle_samples(x) // 20)))
    xs = moving_mean(x, w) if w > 1 else x
    v = np.gradient(xs)
    return v < 0.0, v > 0.0


def loop_energy(force: np.ndarray, x: np.ndarray) -> tuple[float, float]:
    """(−∮F dx over the whole record in N·mm, number of cycles).

    The number of cycles is the travelled path divided by twice the stroke, so the energy
    per cycle is the first value divided by the second.
    """
    f = np.asarray(force, dtype=np.float64)
    x = np.asarray(x, dtype=np.float64)
    dx = np.diff(x)
    work = -float(np.sum(0.5 * (f[1:] + f[:-1]) * dx))
    stroke = float(np.ptp(x))
    cycles = float(np.sum(np.abs(dx))) / (2.0 * stroke) if stroke > 0 else 0.0
    return work, cycles


def _rms(e: np.ndarray) -> float:
    return float(np.sqrt(np.mean(e * e))) if e.size else float("nan")


def measured_parts(
    measured: np.ndarray, x: np.ndarray
) -> tuple[float, float, float, np.ndarray, np.ndarray]:
    """What :func:`metrics` takes from the measurement alone: (std of the measured force (N),
    its loop energy −∮F dx (N·mm) and the cycles of ``x`` (:func:`loop_energy`), and
    :func:`branch_masks` of ``x``) — the same for every model predicting the same record."""
    y = np.asarray(measured, dtype=np.float64)
    w_meas, cycles = loop_energy(y, x)
    stretch, release = branch_masks(x)
    return float(np.std(y)), w_meas, cycles, stretch, release


def metrics(
    measured: np.ndarray,
    predicted: np.ndarray,
    x: np.ndarray,
    parts: tuple[float, float, float, np.ndarray, np.ndarray] | None = None,
) -> dict:
    """All validation metrics of ``predicted`` against ``measured`` force (N) along ``x`` (mm).

    ``parts``: :func:`measured_parts` of ``measured`` and ``x``, when the caller keeps them
    (default: computed here).

    Returns ``{"rmse", "nrmse", "fit_percent", "max_error", "energy_error_percent",
    "energy_measured_mJ_per_cycle", "energy_model_mJ_per_cycle", "branch_rmse":
    {"stretch", "release"}}`` (floats; NaN where undefined, e.g. no cycle).
    """
    y = np.asarray(measured, dtype=np.float64)
    yh = np.asarray(predicted, dtype=np.float64)
    if y.shape != yh.shape or y.shape != np.shape(x):
        raise ValueError(
            f"shape mismatch: measured {y.shape}, predicted {yh.shape}, x {np.shape(x)}"
        )
    e = yh - y
    rmse = _rms(e)
    sd, w_meas, cycles, stretch, release = parts if parts is not None else measured_parts(y, x)
    nrmse = rmse / sd if sd > 0 else float("nan")
    w_mod, _ = loop_energy(yh, x)
    if cycles > 0 and abs(w_meas) > 0:
        e_meas, e_mod = w_meas / cycles, w_mod / cycles
        eerr = 100.0 * (e_mod - e_meas) / abs(e_meas)
    else:
        e_meas = e_mod = eerr = float("nan")
    return {
        "rmse": rmse,
        "nrmse": nrmse,
        "fit_percent": 100.0 * (1.0 - nrmse),
        "max_error": float(np.max(np.abs(e))) if e.size else float("nan"),
        "energy_error_percent": float(eerr),
        "energy_measured_mJ_per_cycle": float(e_meas),
        "energy_model_mJ_per_cycle": float(e_mod),
        "branch_rmse": {"stretch": _rms(e[stretch]), "release": _rms(e[release])},
    }


def loop_direction(force: np.ndarray, x: np.ndarray) -> float:
    """Mean tension on the stretch branch minus on the release branch (N), at equal x.

    Positive for a physical loop (friction makes tension higher while the muscle is being
    stretched).  Compared bin by bin in x so that the force–position slope cancels.
    """
    f = np.asarray(force, dtype=np.float64)
    x = np.asarray(x, dtype=np.float64)
    stretch, release = branch_masks(x)
    lo, hi = np.percentile(x, [10, 90])
    if hi <= lo:
        return 0.0
    edges = np.linspace(lo, hi, 11)
    diffs = []
    for a, b in itertools.pairwise(edges):
        inb = (x >= a) & (x < b)
        s, r = inb & stretch, inb & release
        if s.any() and r.any():
            diffs.append(float(np.mean(f[s]) - np.mean(f[r])))
    return float(np.mean(diffs)) if diffs else 0.0


def information_criteria(
    rss: float, n: int, k: int, n_eff: float | None = None
) -> tuple[float, float]:
    """(AIC, BIC) of a least-squares fit — the one definition every fit in pmalab uses.

    ``N_eff·ln(RSS/N) + 2k`` and ``N_eff·ln(RSS/N) + k·ln N_eff``: ``rss`` the residual sum
    of squares over ``n`` rows, ``k`` free parameters, ``n_eff`` the effective number of
    independent rows (a free-run residual is autocorrelated; default ``n``).
    """
    ne = float(n if n_eff is None else n_eff)
    ll = ne * math.log(max(rss / max(n, 1), 1e-300))
    return ll + 2 * k, ll + k * math.log(max(ne, 2.0))
