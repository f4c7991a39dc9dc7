"""Residual diagnostics: where a model fails, and the pattern that names the missing effect.

The residual is r = measured − model force (N): r > 0 where the model's tension is too low.
For one run we give

* binned means of r against position, velocity, sign of velocity, acceleration, the
  measured muscle pressure's deviation from nominal, time and loop branch, each with a 95 %
  confidence interval.  The residual of a free-run prediction is strongly autocorrelated,
  so the interval uses an *effective* count per bin, n / τ_int (τ_int: integrated
  autocorrelation time of r), not n — otherwise every wiggle looks significant;
* the residual's autocorrelation and its cross-correlation with the input (the drive
  position) with the ±1.96/√N white-noise bounds;
* the localised failure: r.m.s. error in each cell of (branch × third of the stroke) and by
  loop phase, and the worst cell in words ("stretch branch, high contraction ...").

Across runs: mean and r.m.s. residual per pressure level and per test frequency.
Sign conventions: x contraction (mm), stretch branch = x falling (ẋ < 0), release (the
muscle contracts) = x rising.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from pmalab.identify.signals import Signals

N_BINS = 12
#: the binned variables diagnosis.json holds, with their units
BINNED_UNITS = {
    "position": "mm",
    "velocity": "mm/s",
    "velocity_sign": "-",
    "acceleration": "mm/s²",
    "pressure_deviation": "MPa",
    "time": "s",
    "branch": "-",
}


def integrated_act(r: np.ndarray, max_lag: int | None = None) -> float:
    """Integrated autocorrelation time τ_int = 1 + 2·Σρ_k (to the first ρ_k ≤ 0), in samples."""
    r = np.asarray(r, dtype=np.float64) - float(np.mean(r))
    n = r.shape[0]
    if n < 4 or not np.any(r):
        return 1.0
    nfft = 1 << (2 * n - 1).bit_length()
    f = np.fft.rfft(r, nfft)
    acf = np.fft.irfft(f * np.conj(f), nfft)[:n]
    acf /= acf[0]
    m = max_lag or n // 2
    tau = 1.0
    for k in range(1, m):
        if acf[k] <= 0.0:
            break
        tau += 2.0 * acf[k]
    return float(min(max(tau, 1.0), n))


def _ci_scale(r: np.ndarray) -> float:
    """How many raw samples make one independent one (τ_int of the residual)."""
    return integrated_act(r[:: max(1, r.shape[0] // 4000)]) * max(1, r.shape[0] // 4000)


def binned_mean(
    values: np.ndarray,
    r: np.ndarray,
    tau: float,
    unit: str,
    n_bins: int = N_BINS,
    categories: Sequence[float] | None = None,
) -> dict[str, Any]:
    """Mean residual per bin of ``values`` with a 95 % CI using n_eff = n / tau per bin.

    ``categories``: exact category values (e.g. −1, +1) instead of equal-width bins over
    the 1st–99th percentile range.  Empty bins give ``None``.
    """
    if categories is not None:
        idx = [values == c for c in categories]
        centers = [float(c) for c in categories]
    else:
        lo, hi = np.percentile(values, [1.0, 99.0])
        if not hi > lo:
            lo, hi = float(values.min()) - 0.5, float(values.max()) + 0.5
        edges = np.linspace(lo, hi, n_bins + 1)
        which = np.clip(np.digitize(values, edges) - 1, 0, n_bins - 1)
        idx = [which == i for i in range(n_bins)]
        centers = [float(c) for c in 0.5 * (edges[1:] + edges[:-1])]
    mean: list[float | None] = []
    ci: list[float | None] = []
    count: list[int] = []
    for m in idx:
        n = int(m.sum())
        count.append(n)
        if n < 3:
            mean.append(None)
            ci.append(None)
            continue
        rv = r[m]
        n_eff = max(n / tau, 1.0)
        mean.append(float(np.mean(rv)))
        ci.append(float(1.96 * np.std(rv, ddof=1) / np.sqrt(n_eff)))
    return {"centers": centers, "mean": mean, "ci95": ci, "count": count, "unit": unit}


def correlation(a: np.ndarray, b: np.ndarray, max_lag: int) -> np.ndarray:
    """Normalised cross-correlation c[k] = corr(a[t], b[t − k]) for k = −max_lag..max_lag."""
    a = a - a.mean()
    b = b - b.mean()
    n = a.shape[0]
    nfft = 1 << (2 * n - 1).bit_length()
    c = np.fft.irfft(np.fft.rfft(a, nfft) * np.conj(np.fft.rfft(b, nfft)), nfft)
    norm = np.sqrt(np.sum(a * a) * np.sum(b * b)) or 1.0
    lags = np.arange(-max_lag, max_lag + 1)
    return c[lags % nfft] / norm


def _lag_grid(
    t: np.ndarray, frequency_Hz: float | None, n_lags: int = 60
) -> tuple[int, int, float]:
    """(stride, max lag in samples, dt): lags up to one cycle (≤ 5 s), about n_lags points."""
    dt = float(np.median(np.diff(t)))
    span = min(1.0 / frequency_Hz if frequency_Hz else 2.0, 5.0, 0.5 * float(t[-1] - t[0]))
    max_lag = max(int(span / dt), 1)
    stride = max(1, max_lag // n_lags)
    return stride, max_lag, dt


def branch_of(v: np.ndarray) -> np.ndarray:
    """−1 on the stretch branch (x falling), +1 on the release branch (x rising)."""
    return np.where(v < 0.0, -1.0, 1.0)


def loop_regions(x: np.ndarray, v: np.ndarray, r: np.ndarray) -> list[dict[str, Any]]:
    """r.m.s. and mean residual in each (branch × third of the stroke) cell."""
    lo, hi = np.percentile(x, [0.5, 99.5])
    edges = [lo + (hi - lo) * k / 3.0 for k in range(4)]
    names = ("low contraction", "mid contraction", "high contraction")
    which = np.digitize(x, edges[1:3])  # 0, 1, 2: the stroke's thirds
    out = []
    for bname, bmask in (
        ("stretch branch (x falling)", v < 0),
        ("release branch (x rising)", v >= 0),
    ):
        for i, pname in enumerate(names):
            m = bmask & (which == i)
            n = int(m.sum())
            out.append(
                {
                    "branch": bname,
                    "position": pname,
                    "x_range_mm": [float(edges[i]), float(edges[i + 1])],
                    "n": n,
                    "rms": float(np.sqrt(np.mean(r[m] ** 2))) if n else None,
                    "mean": float(np.mean(r[m])) if n else None,
                }
            )
    return out


def analytic_signal(x: np.ndarray) -> np.ndarray:
    """The analytic signal x + i·H[x] of a real 1-D ``x`` (H: the Hilbert transform), by the
    FFT: the negative frequencies zeroed, the positive ones doubled.

    The same operations as ``scipy.signal.hilbert`` (the same numbers), written out here:
    importing ``scipy.signal`` (and the ``scipy.stats`` it loads) costs a diagnosis more
    start-up time than its residual diagnostics take.

    Parameters
    ----------
    x
        Real samples, 1-D.

    Returns
    -------
    numpy.ndarray
        Complex, the length of ``x``; its angle is the instantaneous phase (rad).
    """
    from scipy import fft

    n = x.shape[0]
    xf: np.ndarray = np.asarray(fft.fft(x, n))  # (the array itself: no copy)
    if n % 2 == 0:
        xf[1 : n // 2] *= 2.0
        xf[n // 2 + 1 : n] = 0.0
    else:
        xf[1 : (n + 1) // 2] *= 2.0
        xf[(n + 1) // 2 : n] = 0.0
    return np.asarray(fft.ifft(xf))


def loop_phase(x: np.ndarray, r: np.ndarray, n_bins: int = 8) -> dict[str, Any]:
    """r.m.s. and mean residual by loop phase (0° = maximum contraction, 180° = minimum)."""
    z = analytic_signal(np.asarray(x - np.mean(x)))
    ph = np.degrees(np.angle(z)) % 360.0
    edges = np.linspace(0.0, 360.0, n_bins + 1)
    which = np.clip(np.digitize(ph, edges) - 1, 0, n_bins - 1)
    rms, mean = [], []
    for i in range(n_bins):
        m = which == i
        rms.append(float(np.sqrt(np.mean(r[m] ** 2))) if m.any() else None)
        mean.append(float(np.mean(r[m])) if m.any() else None)
    return {
        "centers_deg": [float(c) for c in 0.5 * (edges[1:] + edges[:-1])],
        "rms": rms,
        "mean": mean,
        "note": "0° = maximum contraction; 0°–180° stretch branch (x falling), 180°–360° release",
    }


def describe_worst(regions: list[dict[str, Any]], total_rms: float) -> str:
    """The worst cell in words, with the sign of the error."""
    cells = [c for c in regions if c["rms"] is not None and c["n"] > 0]
    if not cells:
        return "no data"
    w = max(cells, key=lambda c: c["rms"])
    sense = "model tension too low" if w["mean"] > 0 else "model tension too high"
    lo, hi = w["x_range_mm"]
    return (
        f"{w['branch'].split(' (')[0]}, {w['position']} (x {lo:.1f}–{hi:.1f} mm): "
        f"rms error {w['rms']:.3g} N ({w['rms'] / total_rms:.1f}× the run's {total_rms:.3g} N), "
        f"mean {w['mean']:+.3g} N: {sense}"
    )


def run_diagnostics(sig: Signals, force: np.ndarray, model_force: np.ndarray) -> dict[str, Any]:
    """Every single-run diagnostic of the residual.

    Parameters
    ----------
    sig
        The run's signals at full rate (contraction x mm, its rates, pressure MPa, time s).
    force
        Measured tension, N (positive pulls).
    model_force
        The model's tension, N.

    Returns
    -------
    dict
        Of the residual r = measured − model (N): its mean binned by position, velocity,
        its sign, acceleration, pressure deviation, time and loop branch (``binned``, each
        with a confidence band); its autocorrelation (``acf``) and cross-correlation with
        the position (``ccf_input``, lags in s, ±1.96/√n bounds); the loop regions and the
        worst one; ``rmse`` (N) and ``nrmse``.
    """
    r = np.asarray(force, dtype=np.float64) - np.asarray(model_force, dtype=np.float64)
    tau = _ci_scale(r)
    v = sig.v
    binned = {
        "position": binned_mean(sig.x, r, tau, "mm"),
        "velocity": binned_mean(v, r, tau, "mm/s"),
        "velocity_sign": binned_mean(np.sign(v), r, tau, "-", categories=(-1.0, 1.0)),
        "acceleration": binned_mean(sig.a, r, tau, "mm/s²"),
        "pressure_deviation": binned_mean(sig.p - sig.p_nom, r, tau, "MPa"),
        "time": binned_mean(sig.t - sig.t[0], r, tau, "s"),
        "branch": binned_mean(branch_of(v), r, tau, "-", categories=(-1.0, 1.0)),
    }
    stride, max_lag, dt = _lag_grid(sig.t, sig.frequency_Hz)
    n = r.shape[0]
    bound = float(1.96 / np.sqrt(n))
    acf = correlation(r, r, max_lag)[max_lag:][::stride]
    ccf = correlation(r, sig.x, max_lag)[::stride]
    lags_acf = np.arange(0, max_lag + 1)[::stride] * dt
    lags_ccf = np.arange(-max_lag, max_lag + 1)[::stride] * dt
    regions = loop_regions(sig.x, v, r)
    total = float(np.sqrt(np.mean(r**2)))
    k_peak = int(np.argmax(np.abs(ccf)))
    return {
        "binned": binned,
        "acf": {
            "lags_s": [float(x) for x in lags_acf],
            "values": [float(x) for x in acf],
            "bound95": bound,
        },
        "ccf_input": {
            "lags_s": [float(x) for x in lags_ccf],
            "values": [float(x) for x in ccf],
            "bound95": bound,
            "input": "position",
            "peak_lag_s": float(lags_ccf[k_peak]),
        },
        "worst_region": describe_worst(regions, total),
        "regions": regions,
        "loop_phase": loop_phase(sig.x, r),
        "rmse": total,
        "nrmse": float(total / np.std(force)) if np.std(force) > 0 else None,
        "tau_int_s": float(tau * dt),
    }


def campaign_diagnostics(items: Sequence[tuple[float, float | None, np.ndarray]]) -> dict[str, Any]:
    """Residual by pressure level and frequency across runs: items = (p_nom, f, residual)."""
    out: dict[str, Any] = {}
    for name, idx, unit in (("pressure_level", 0, "MPa"), ("frequency", 1, "Hz")):
        groups: dict[float, list[np.ndarray]] = {}
        for it in items:
            key = it[idx]
            if key is None:
                continue
            groups.setdefault(round(float(key), 4), []).append(it[2])
        centers = sorted(groups)
        mean, rms, ci = [], [], []
        for c in centers:
            rs = groups[c]
            allr = np.concatenate(rs)
            per_run = [float(np.sqrt(np.mean(x**2))) for x in rs]
            mean.append(float(np.mean(allr)))
            rms.append(float(np.sqrt(np.mean(allr**2))))
            ci.append(
                float(1.96 * np.std(per_run, ddof=1) / np.sqrt(len(per_run)))
                if len(per_run) > 1
                else None
            )
        out[name] = {"centers": centers, "mean": mean, "rms": rms, "ci95_rms": ci, "unit": unit}
    return out


# --------------------------------------------------------------- where the rest lies
#: the "motion band" ends at this many times the motion's fundamental f0
MOTION_HARMONICS = 10
#: position bins per branch of the loop for the loop-locked part of the residual
LOOP_BINS = 24


def _fundamental(t: np.ndarray, x: np.ndarray) -> float | None:
    """The motion's fundamental (Hz) from the position's spectrum (mean and trend removed)."""
    n = len(t)
    if n < 32 or t[-1] <= t[0]:
        return None
    xs = x - np.polyval(np.polyfit(t - t[0], x, 1), t - t[0])
    spec = np.abs(np.fft.rfft(xs * np.hanning(n)))
    k = int(np.argmax(spec[2:])) + 2
    return float(k * (n - 1) / ((t[-1] - t[0]) * n))


def _seamless(y: np.ndarray) -> np.ndarray:
    """``y`` minus the straight line through its first and last samples (and its mean): its
    periodic extension has no jump at the seam."""
    y = np.asarray(y, float)
    if y.size < 2:
        return y - float(np.mean(y)) if y.size else y
    z = y - np.linspace(float(y[0]), float(y[-1]), y.size)
    return z - float(np.mean(z))


def residual_shares(
    t: np.ndarray,
    x: np.ndarray,
    r: np.ndarray,
    noise_sigma_N: float,
    frequency_Hz: float | None = None,
    model_force: np.ndarray | None = None,
) -> dict[str, Any]:
    """Split a held-out run's residual power beyond the noise into where it lies.

    ``r`` = measured − model force (N) of a free-run prediction, ``x`` the contraction
    (mm), ``noise_sigma_N`` the record's own noise (pmalab.identify.noise),
    ``frequency_Hz`` the motion's fundamental f0 (read off the position's spectrum when not
    given).  Shares of the structured power P = mean(r²) − σ² (fractions in [0, 1] that
    sum to ≤ 1), taken in this order:

    * ``offset``: the residual's mean: a constant the model carries on the identification
      runs but not on this one (a session offset: load-cell zero, temperature);
    * ``loop``: the mean residual at each place of the loop (branch × position bin): an
      error that repeats every cycle where the loop is, i.e. the loop's shape;
    * ``above_band``: of what is left, the part above 10.5·f0: faster than the motion
      (vibration, valve, mains pickup: the rig, not the muscle);
    * ``other``: the rest, in the motion band but not tied to the loop (slow drift,
      cycle-to-cycle change).

    The white noise's expected share of each part (σ² spread evenly up to Nyquist, σ²·bins/n
    for the binned means) is removed first, so a model at the noise floor has P ≈ 0.

    With ``model_force`` (the prediction, N), ``above_band_source`` says whose the fast part
    is: ``"model"`` when the prediction carries more power above the band than the
    measurement (a model term differentiating a noisy position injects it), else
    ``"measurement"`` (the rig).

    Parameters
    ----------
    t
        Sample times, s.
    x
        Contraction, mm (positive = shorter).
    r
        Residual, measured − model tension, N, of a free-run prediction.
    noise_sigma_N
        The record's own noise SD, N (:mod:`pmalab.identify.noise`).
    frequency_Hz
        The motion's fundamental f0, Hz (``None``: read off the position's spectrum).
    model_force
        The prediction, N, to say whose the fast part is.

    Returns
    -------
    dict
        ``structured_power_N2`` (P, N²), ``rms_N``, ``noise_sigma_N``, ``f0_Hz`` and the
        shares ``offset``, ``loop``, ``above_band``, ``other`` (fractions of P), plus
        ``above_band_source`` with ``model_force``.
    """
    t = np.asarray(t, float)
    r = np.asarray(r, float)
    x = np.asarray(x, float)
    n = len(t)
    mean_sq = float(np.mean(r**2)) if n else 0.0
    sigma2 = float(noise_sigma_N) ** 2
    structured = max(mean_sq - sigma2, 0.0)
    f0 = (
        frequency_Hz
        if frequency_Hz and frequency_Hz > 0
        else (
            _fundamental(np.linspace(t[0], t[-1], n), np.interp(np.linspace(t[0], t[-1], n), t, x))
            if n >= 32
            else None
        )
    )
    out: dict[str, Any] = {
        "structured_power_N2": structured,
        "rms_N": float(np.sqrt(mean_sq)),
        "noise_sigma_N": float(noise_sigma_N),
        "f0_Hz": f0,
        "offset": 0.0,
        "loop": 0.0,
        "above_band": 0.0,
        "other": 0.0,
        "above_band_source": None,
    }
    if structured <= 0.0 or f0 is None or n < 4 * LOOP_BINS:
        return out
    mean = float(np.mean(r))
    rc = r - mean
    # loop-locked part: mean residual per (branch, position bin)
    v = np.gradient(x, t)
    edges = np.quantile(x, np.linspace(0.0, 1.0, LOOP_BINS + 1))
    pos = np.clip(np.searchsorted(edges, x, side="right") - 1, 0, LOOP_BINS - 1)
    cell = pos + LOOP_BINS * (v > 0)
    counts = np.bincount(cell, minlength=2 * LOOP_BINS)
    sums = np.bincount(cell, weights=rc, minlength=2 * LOOP_BINS)
    means = np.divide(sums, counts, out=np.zeros_like(sums), where=counts > 0)
    locked = means[cell]
    used = int(np.count_nonzero(counts))
    loop_p = max(float(np.mean(locked**2)) - sigma2 * used / n, 0.0)
    # what the loop does not explain: above the motion band, or in it
    rest = rc - locked
    tu = np.linspace(t[0], t[-1], n)
    ru = np.interp(tu, t, rest)
    # the FFT extends the record periodically: a record that ends elsewhere than it starts
    # (a steady window of a few cycles, a slow drift) jumps at the seam, and the jump's
    # broadband leakage would be read as fast content.  The straight line through the end
    # points is taken out before the split (its power is slow: it stays in the band).
    spec = np.abs(np.fft.rfft(_seamless(ru))) ** 2
    spec[1:] *= 2.0
    freqs = np.fft.rfftfreq(n, d=(tu[-1] - tu[0]) / (n - 1))
    rest_var = float(np.mean(ru**2))
    above = freqs > (MOTION_HARMONICS + 0.5) * f0
    nyq = float(freqs[-1]) if freqs[-1] > 0 else 1.0
    # Parseval: the power above the band, as a share of all the rest's power
    frac_above = min(float(spec[above].sum()) / n**2 / rest_var, 1.0) if rest_var > 0 else 0.0
    width_above = max(nyq - (MOTION_HARMONICS + 0.5) * f0, 0.0) / nyq
    noise_rest = sigma2 * (1.0 - used / n)
    above_p = max(frac_above * rest_var - noise_rest * width_above, 0.0)
    other_p = max((1.0 - frac_above) * rest_var - noise_rest * (1.0 - width_above), 0.0)
    if model_force is not None and above_p > 0:
        measured = np.interp(tu, t, r + np.asarray(model_force, float))
        pred = np.interp(tu, t, np.asarray(model_force, float))

        def fast(sig: np.ndarray) -> float:
            sp = np.abs(np.fft.rfft(_seamless(sig))) ** 2
            return float(sp[above].sum())

        out["above_band_source"] = "model" if fast(pred) > fast(measured) else "measurement"
    parts = {"offset": mean**2, "loop": loop_p, "above_band": above_p, "other": other_p}
    s = sum(parts.values())
    if s > 0:
        scale = min(structured / s, 1.0) / structured  # shares of P, never above 1 in all
        out.update({k: float(val * scale) for k, val in parts.items()})
    return out


#: what each share points at, in the summary's words
RESIDUAL_NEXT = {
    "loop": "where the loop is, the same every cycle: the loop's shape (try another law, "
    "or an effect that changes the loop)",
    "above_band": "above the motion band: a disturbance from the rig (vibration, valve, "
    "pickup), not the muscle",
    "above_band_model": "above the motion band, and the model's own: its prediction carries "
    "more fast content than the measurement (a term differentiating a "
    "noisy position: smooth the velocity it uses)",
    "offset": "a constant offset between identification and validation sessions (a "
    "systematic offset the pressure laws cannot carry: re-zero the load cell, "
    "or identify on runs of the same session)",
    "other": "in the motion band but off its harmonics: slow drift or non-periodic "
    "behaviour within the run",
}


def residual_next_step(per_run: Sequence[dict[str, Any]]) -> dict[str, Any]:
    """The campaign's residual shares and the next thing to look at.

    Parameters
    ----------
    per_run
        Each held-out run's :func:`residual_shares`.

    Returns
    -------
    dict
        The shares ``loop``, ``above_band``, ``offset``, ``other`` averaged with each run's
        structured power as weight; ``above_band_source``; ``next``: the largest share
        when it holds at least a third of what is left (else ``None``); ``text``: the
        sentence the summary prints.
    """
    keys = ("loop", "above_band", "offset", "other")
    w = np.array([d["structured_power_N2"] for d in per_run], float)
    if not per_run or w.sum() <= 0:
        return {**{k: 0.0 for k in keys}, "next": None, "text": ""}
    shares = {k: float(np.sum([d[k] * wi for d, wi in zip(per_run, w)]) / w.sum()) for k in keys}
    top = max(keys, key=lambda k: shares[k])
    # whose the fast part is: the model's own when it is so on most of that power
    src_w = {"model": 0.0, "measurement": 0.0}
    for d, wi in zip(per_run, w):
        if d.get("above_band_source") in src_w:
            src_w[d["above_band_source"]] += d["above_band"] * wi
    shares_src = max(src_w, key=lambda k: src_w[k]) if any(src_w.values()) else None
    ordered = sorted(keys, key=lambda k: -shares[k])
    names = {
        "loop": "tied to the loop",
        "above_band": "above the motion band",
        "offset": "session offset",
        "other": "in band, not tied to the loop",
    }
    listed = ", ".join(f"{100 * shares[k]:.0f} % {names[k]}" for k in ordered if shares[k] >= 0.05)
    nxt = top if shares[top] >= 1 / 3 else None
    why = RESIDUAL_NEXT[top]
    if top == "above_band" and shares_src == "model":
        why = RESIDUAL_NEXT["above_band_model"]
    text = (
        f"Where the rest lies ({listed}): mostly {why}."
        if nxt
        else (f"Where the rest lies ({listed}): no single place." if listed else "")
    )
    return {**shares, "above_band_source": shares_src, "next": nxt, "text": text}
