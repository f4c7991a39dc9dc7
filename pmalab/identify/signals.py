"""The signals a force law is driven by, prepared once per run.

Rate-independent hysteresis laws integrate |dx|.  Driven by raw 500 Hz position, sensor
noise dominates the per-sample increments (at 0.15 Hz the true increment is a few µm), so
the accumulated |dx| is mostly noise and h is biased toward zero.  We therefore drive every
law with a zero-phase (forward-backward Butterworth) filtered position whose cut-off sits
well above the excitation frequency: the filter removes the noise without shifting the loop
in time (no phase lag, so no fake loop width).  The elasto-slide laws (Maxwell-slip,
Prandtl-Ishlinskii) are driven by a narrower band (:func:`slide_cutoff_Hz`, ``x_slide``):
their stiff small elements pass the position noise left in the wide band to the force
through their stiffness while they stick.

Velocity and acceleration come from ONE estimator (:func:`derivatives`), used by every
effect that needs them (viscous friction, inertia, rate-dependent terms) in identification,
validation, diagnosis and the reports: the position low-passed (zero phase) at the top of
the *motion band* — ``DERIVATIVE_HARMONICS`` × the excitation frequency, at least
``DERIVATIVE_MIN_HZ`` and at most a fifth of the sample rate — then central differences
against the *measured* time stamps (never the nominal rate).  The band follows the motion,
not the law's drive filter: a derivative multiplies position noise by 2πf at each frequency,
so the drive position's wide band (60× the excitation, kept for sharp reversals) would put
the sensor noise into every velocity term (at 2 Hz, 0.015 mm rms position noise gives
≈ 3 mm/s rms velocity noise at a 100 Hz band, ≈ 0.3 mm/s at 20 Hz), and a viscous term
c·ẋ fitted on it adds that noise to the model's own prediction.  The forward (plant)
simulation and the controllers integrate velocity as a state and differentiate nothing.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from pmalab.identify.zero_phase import butter2, filtfilt2
from pmalab.runfile import Run

#: cut-off of the position filter as a multiple of the excitation frequency.  Chosen on
#: model-generated data with 0.015 mm position noise (tests/identify_synth.py): at 15× a
#: 0.25 Hz triangle (reversals rounded by a 70 ms regulator lag) validates at 2.3× the
#: force-noise floor because the filter rounds the reversals; at 60× every sine and
#: triangle case is within 1.09× of the floor and parameter recovery is unchanged (< 0.6 %).
CUTOFF_MULTIPLE = 60.0


#: the derivative estimator's band: this many harmonics of the excitation (inside the motion
#: band of the residual diagnostics, 10 harmonics; an isobaric sine or a lag-rounded triangle
#: has little velocity beyond its 5th harmonic, and acceleration noise grows as the band^2.5)
DERIVATIVE_HARMONICS = 6.0
#: ... and never below this (Hz): a slow test's reversals still need a few Hz
DERIVATIVE_MIN_HZ = 2.0


def derivative_cutoff_Hz(sample_rate_Hz: float, frequency_Hz: float | None) -> float:
    """Band (Hz) of the velocity/acceleration estimator: ``DERIVATIVE_HARMONICS`` × the
    excitation frequency (≥ ``DERIVATIVE_MIN_HZ``, ≤ fs/5); unknown frequency: 0.5 Hz assumed."""
    f = frequency_Hz if frequency_Hz and frequency_Hz > 0 else 0.5
    return float(min(max(DERIVATIVE_HARMONICS * f, DERIVATIVE_MIN_HZ), sample_rate_Hz / 5.0))


def derivatives(
    t: np.ndarray, x: np.ndarray, frequency_Hz: float | None
) -> tuple[np.ndarray, np.ndarray, float]:
    """(ẋ, ẍ, band): velocity (mm/s) and acceleration (mm/s²) of the position ``x`` (mm).

    The one derivative estimator (module docstring): ``x`` low-passed zero phase at
    :func:`derivative_cutoff_Hz`, then central differences against ``t`` (s)."""
    t = np.asarray(t, dtype=np.float64)
    fs = 1.0 / float(np.median(np.diff(t)))
    fc = derivative_cutoff_Hz(fs, frequency_Hz)
    xs = zero_phase_lowpass(t, np.asarray(x, dtype=np.float64), fc)
    v = np.gradient(xs, t)
    return v, np.gradient(v, t), fc


#: share of the position's variance below the motion band of a run whose frequency is unknown
MOTION_BAND_SHARE = 0.999


def motion_band_Hz(t: np.ndarray, x: np.ndarray) -> float:
    """The frequency (Hz) below which :data:`MOTION_BAND_SHARE` of the position's variance
    lies (its spectrum on the median sample interval; the mean and linear trend removed)."""
    t = np.asarray(t, dtype=np.float64)
    y = np.asarray(x, dtype=np.float64)
    if y.size < 16:
        return 0.0
    y = y - np.polyval(np.polyfit(t - t[0], y, 1), t - t[0])
    power = np.abs(np.fft.rfft(y)) ** 2
    power[0] = 0.0
    total = float(power.sum())
    if total <= 0:
        return 0.0
    freqs = np.fft.rfftfreq(y.size, float(np.median(np.diff(t))))
    return float(freqs[int(np.searchsorted(np.cumsum(power), MOTION_BAND_SHARE * total))])


def filter_frequency_Hz(run: Run) -> float | None:
    """The excitation frequency the filters and derivatives are set from.

    The run's ``frequency_Hz`` when known (> 0).  Unknown (absent or 0, as a broadband
    record may say): the filters assume 0.5 Hz, which suits a slow test but would low-pass
    a fast one (a 5–150 Hz multisine) to nothing — so when the position's own motion band
    (:func:`motion_band_Hz`) reaches beyond the band that assumption covers, the band's upper
    edge is taken as the frequency: every filter and the fit's decimation then keep the
    whole band (a 5–150 Hz multisine recorded at 750 Hz: filtered as if declared 150 Hz)."""
    f = run.frequency
    if f is not None and f > 0:
        return f
    band = motion_band_Hz(run.time, run.position)
    if band > DERIVATIVE_HARMONICS * 0.5:
        return band
    return None


def default_cutoff_Hz(sample_rate_Hz: float, frequency_Hz: float | None) -> float:
    """Cut-off of the zero-phase position filter: 60× the excitation (≥ 5 Hz, ≤ fs/5)."""
    f = frequency_Hz if frequency_Hz and frequency_Hz > 0 else 0.5
    return float(min(max(CUTOFF_MULTIPLE * f, 5.0), sample_rate_Hz / 5.0))


#: the elasto-slide laws' drive (Maxwell-slip, Prandtl-Ishlinskii): cut-off this multiple of
#: the excitation, never below the reversals' band (:func:`slide_cutoff_Hz`)
SLIDE_CUTOFF_MULTIPLE = 30.0
#: ... the reversals' band: ``CUTOFF_MULTIPLE`` × the excitation up to this frequency (Hz)
SLIDE_REVERSAL_HZ = 15.0


def slide_cutoff_Hz(sample_rate_Hz: float, frequency_Hz: float | None) -> float:
    """Cut-off (Hz) of the position that drives an elasto-slide law (Maxwell-slip,
    Prandtl-Ishlinskii): ``SLIDE_CUTOFF_MULTIPLE`` × the excitation, never below the
    reversals' band (``CUTOFF_MULTIPLE`` × the excitation up to ``SLIDE_REVERSAL_HZ``), at
    least 5 Hz and at most fs/5 — never above :func:`default_cutoff_Hz`.

    An element of stiffness k that sticks passes position noise to the force as k·δx: the
    stiff small elements these laws fit (slip displacements of 0.1–0.3 mm, 100–300 N/mm)
    turn 0.01 mm of position noise left in the 60× band into 1–3 N of force noise, as
    large as a load cell's.  A scalar-state law (Bouc-Wen, Duhem) saturates toward its
    branch and keeps the 60× band."""
    f = frequency_Hz if frequency_Hz and frequency_Hz > 0 else 0.5
    band = max(SLIDE_CUTOFF_MULTIPLE * f, min(CUTOFF_MULTIPLE * f, SLIDE_REVERSAL_HZ))
    return float(min(max(band, 5.0), sample_rate_Hz / 5.0, default_cutoff_Hz(sample_rate_Hz, f)))


def zero_phase_lowpass(t: np.ndarray, y: np.ndarray, cutoff_Hz: float) -> np.ndarray:
    """4th-order Butterworth, applied forward and backward (zero phase)."""
    fs = 1.0 / float(np.median(np.diff(t)))
    if cutoff_Hz >= 0.45 * fs or y.shape[0] < 30:
        return y.astype(np.float64, copy=True)
    b, a = butter2(cutoff_Hz / (0.5 * fs))  # 2nd order, twice = 4th order
    return filtfilt2(b, a, y, padlen=min(3 * 50, y.shape[0] - 1))


#: :meth:`Signals.from_run`'s signals of the runs :func:`keep_run_signals` named, by (id of
#: the run, cut-off)
_RUN_SIGNALS: dict[tuple[int, float | None], Signals] = {}
#: the runs whose signals are kept (held here, so their ids stay theirs), by id
_KEPT_RUNS: dict[int, Run] = {}


def keep_run_signals(runs: Sequence[Run]) -> None:
    """Keep the :meth:`Signals.from_run` of exactly these run objects in this process (the
    signals of runs named before are forgotten unless named again; ``[]``: none).

    For a worker process that fits many models to the same runs, which nobody changes (a
    diagnosis's candidates: each would filter and differentiate the same identification
    and held-out runs again).  A run changed in place would keep its old signals: never
    for runs a user's code holds."""
    ids = {id(r): r for r in runs}
    if ids.keys() == _KEPT_RUNS.keys() and all(_KEPT_RUNS[i] is r for i, r in ids.items()):
        return
    _KEPT_RUNS.clear()
    _KEPT_RUNS.update(ids)
    _RUN_SIGNALS.clear()
    _DERIVED.clear()


#: values derived from a kept run's signals and force (:func:`kept_derived`), with the
#: signals and force they came from
_DERIVED: dict[tuple[int, int, str], tuple[Signals, np.ndarray, Any]] = {}


def kept_derived(sig: Signals, force: np.ndarray, name: str, make: Callable[[], Any]) -> Any:
    """``make()`` — a value that depends only on ``sig`` and ``force`` (``name`` says
    which) — computed once for the signals of a run :func:`keep_run_signals` named (the
    same objects for every fit of that run), every time for any other signals."""
    kept = any(v is sig for v in _RUN_SIGNALS.values())
    if not kept:
        return make()
    key = (id(sig), id(force), name)
    got = _DERIVED.get(key)
    if got is not None and got[0] is sig and got[1] is force:
        return got[2]
    value = make()
    _DERIVED[key] = (sig, force, value)
    return value


@dataclass(frozen=True)
class Signals:
    """Inputs of a force law for one run.  Units: s, mm, mm/s, mm/s², MPa.

    ``x`` is the filtered contraction that drives the model; ``x_raw`` the measurement;
    ``v`` and ``a`` its derivatives from :func:`derivatives` (band ``derivative_Hz``).
    ``p`` is the filtered measured muscle pressure, ``p_nom`` the run's nominal pressure.
    ``t_ref`` (s): the record's reference time for slow terms (a drift d·(t − t_ref)); None:
    the middle of ``t``'s span.  ``p_mean`` (MPa): the record's mean measured pressure (the
    part that varies within the run is p − p_mean); None: the mean of ``p``.  A part of a
    record (:meth:`head`, :meth:`every`) keeps its record's.
    """

    t: np.ndarray
    x: np.ndarray
    v: np.ndarray
    a: np.ndarray
    p: np.ndarray
    p_nom: float
    x_raw: np.ndarray
    frequency_Hz: float | None = None
    cutoff_Hz: float = 10.0
    derivative_Hz: float = 5.0
    t_ref: float | None = None
    p_mean: float | None = None
    #: the contraction (mm) that drives an elasto-slide law (:func:`slide_cutoff_Hz`); None:
    #: ``x``
    x_slide: np.ndarray | None = None

    def slide_drive(self) -> Signals:
        """These signals with ``x_slide`` as the position ``x`` (itself when there is none):
        what a model with an elasto-slide law is driven by.  Made once per signals object
        (a fit asks for it at every prediction) and kept beside it, never pickled."""
        if self.x_slide is None:
            return self
        got = self.__dict__.get("_slide_drive")
        if got is None:
            got = replace(self, x=self.x_slide, x_slide=None)
            object.__setattr__(self, "_slide_drive", got)  # a cache, not a field
        return got

    def __getstate__(self) -> dict[str, Any]:
        # the kept slide drive is derived: a copy sent to a worker makes its own
        return {k: v for k, v in self.__dict__.items() if k != "_slide_drive"}

    @classmethod
    def from_arrays(
        cls,
        t: np.ndarray,
        x: np.ndarray,
        p: np.ndarray | float,
        p_nom: float | None = None,
        frequency_Hz: float | None = None,
        cutoff_Hz: float | None = None,
    ) -> Signals:
        t = np.asarray(t, dtype=np.float64)
        x_raw = np.asarray(x, dtype=np.float64)
        p_arr = np.broadcast_to(np.asarray(p, dtype=np.float64), t.shape).copy()
        fs = 1.0 / float(np.median(np.diff(t)))
        fc = cutoff_Hz if cutoff_Hz is not None else default_cutoff_Hz(fs, frequency_Hz)
        xf = zero_phase_lowpass(t, x_raw, fc)
        pf = zero_phase_lowpass(t, p_arr, fc)
        # the elasto-slide laws' drive: its own narrower band, unless a cut-off was asked for
        fcs = slide_cutoff_Hz(fs, frequency_Hz) if cutoff_Hz is None else fc
        xs = zero_phase_lowpass(t, x_raw, fcs) if fcs < fc else None
        v, a, fd = derivatives(t, x_raw, frequency_Hz)
        pn = float(np.mean(p_arr)) if p_nom is None else float(p_nom)
        return cls(
            t=t,
            x=xf,
            v=v,
            a=a,
            p=pf,
            p_nom=pn,
            x_raw=x_raw,
            frequency_Hz=frequency_Hz,
            cutoff_Hz=fc,
            derivative_Hz=fd,
            p_mean=float(np.mean(p_arr)),
            x_slide=xs,
        )

    @classmethod
    def from_run(cls, run: Run, cutoff_Hz: float | None = None) -> Signals:
        """The run's signals (filtered position and pressure, derivatives).

        For the runs :func:`keep_run_signals` named, computed once and served again to
        every later fit of the same run object (the same arrays, which no consumer writes
        to)."""
        kept = _KEPT_RUNS.get(id(run)) is run
        key = (id(run), cutoff_Hz)
        if kept and key in _RUN_SIGNALS:
            return _RUN_SIGNALS[key]
        sig = cls.from_arrays(
            run.time,
            run.position,
            run.muscle_pressure,
            p_nom=run.nominal_pressure,
            frequency_Hz=filter_frequency_Hz(run),
            cutoff_Hz=cutoff_Hz,
        )
        if kept:
            _RUN_SIGNALS[key] = sig
        return sig

    @property
    def mean_pressure(self) -> float:
        """``p_mean``, or the mean of ``p`` (MPa)."""
        return float(self.p_mean) if self.p_mean is not None else float(np.mean(self.p))

    @property
    def reference_time(self) -> float:
        """``t_ref``, or the middle of the time span (s)."""
        return float(self.t_ref) if self.t_ref is not None else 0.5 * float(self.t[0] + self.t[-1])

    def with_position(
        self,
        x: np.ndarray,
        v: np.ndarray | None = None,
        a: np.ndarray | None = None,
        x_slide: np.ndarray | None = None,
    ) -> Signals:
        """A copy driven by another (already filtered) position; its derivatives ``v``, ``a``
        (default: recomputed by :func:`derivatives` from ``x``) and the elasto-slide laws'
        drive ``x_slide`` (default: ``x``)."""
        if v is None or a is None:
            v, a, _ = derivatives(self.t, x, self.frequency_Hz)
        # ``replace(self, x=x, v=v, a=a, x_slide=x_slide)`` without the frozen __init__'s
        # thirteen object.__setattr__ calls (a delayed drive is made at every prediction):
        # the same fields, the kept slide drive (derived from the old position) left out
        new = object.__new__(type(self))
        d = new.__dict__
        d.update(self.__dict__)
        d.pop("_slide_drive", None)
        d.update(x=x, v=v, a=a, x_slide=x_slide)
        return new

    def _sliced(self, s: slice) -> Signals:
        """The samples ``s`` of every per-sample array; the reference time of slow terms
        stays the whole record's."""
        return replace(
            self,
            t=self.t[s],
            x=self.x[s],
            v=self.v[s],
            a=self.a[s],
            p=self.p[s],
            x_raw=self.x_raw[s],
            t_ref=self.reference_time,
            p_mean=self.mean_pressure,
            x_slide=None if self.x_slide is None else self.x_slide[s],
        )

    def head(self, n: int) -> Signals:
        """The first ``n`` samples (filtering and derivatives kept from the whole record,
        the reference time of slow terms kept as the whole record's)."""
        s = slice(0, n)
        return self._sliced(s)

    def every(self, stride: int) -> Signals:
        """Every ``stride``-th sample (filtering and derivatives kept from the full rate).

        For cost functions on long runs.  The position-domain laws integrate the decimated
        path as piecewise linear, which stays accurate while each step is a small part of the
        stroke (keep ≥ ~100 samples per excitation cycle).
        """
        if stride <= 1:
            return self
        s = slice(None, None, stride)
        return self._sliced(s)
