"""A run's pressure label against its measurement: is the nominal pressure what was applied?

A run's nominal muscle pressure comes from a protocol, a file name (``import
--pressure-from-name``) or a lab notebook; the pressure laws θ(p) of identification are
fitted against it.  When the measured mean pressure of the run differs from the label by
more than the measurement can explain, part of what a diagnosis calls "pressure
variation" is the label's offset, not physics.  :func:`check_labels` compares each run's
label with its measured mean and says which runs disagree, by how much.

Tolerance (MPa) of one run: three standard errors of the measured mean (the gauge's noise
rms, estimated from third differences of the pressure channel, over √N) plus the
regulator's setpoint resolution (``REGULATOR_RESOLUTION_MPa``: a 10-bit 0–0.9 MPa
proportional regulator) plus the gauge's own quantisation step (the smallest step between
its distinct readings).  A run whose mean lies further from its label is *offset*.

Pure numpy: runs in through plain arrays, so import and identify use the same check.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass

import numpy as np

#: setpoint resolution of the pressure regulator (MPa): 0.9 MPa over 10 bits
REGULATOR_RESOLUTION_MPa = 0.9 / 1023.0


@dataclass(frozen=True)
class LabelCheck:
    """One run's nominal pressure against its measured mean (MPa)."""

    run: str
    nominal_MPa: float
    measured_MPa: float
    tolerance_MPa: float

    @property
    def offset_MPa(self) -> float:
        """measured mean − nominal (MPa)."""
        return self.measured_MPa - self.nominal_MPa

    @property
    def offset(self) -> bool:
        """The label differs from the measurement beyond the tolerance."""
        return bool(abs(self.offset_MPa) > self.tolerance_MPa)

    def as_json(self) -> dict[str, float | bool | str]:
        return {
            "run": self.run,
            "nominal_MPa": self.nominal_MPa,
            "measured_mean_MPa": self.measured_MPa,
            "offset_kPa": 1000.0 * self.offset_MPa,
            "tolerance_kPa": 1000.0 * self.tolerance_MPa,
            "label_offset": self.offset,
        }


def _noise_rms(p: np.ndarray) -> float:
    """Rms of the gauge noise (MPa) from third differences (robust: median absolute value)."""
    if p.size < 8:
        return 0.0
    d3 = np.diff(p, 3)
    # Δ³ of white noise has variance 20σ²; MAD → σ for a Gaussian
    return float(1.4826 * np.median(np.abs(d3 - np.median(d3))) / np.sqrt(20.0))


def _step(p: np.ndarray) -> float:
    u = np.unique(p)
    d = np.diff(u)
    d = d[d > 0]
    return float(np.min(d)) if d.size else 0.0


def check_label(
    run: str,
    nominal_MPa: float,
    pressure_MPa: np.ndarray,
    regulator_resolution_MPa: float = REGULATOR_RESOLUTION_MPa,
) -> LabelCheck:
    """Compare one run's label with its measured muscle pressure (MPa samples)."""
    p = np.asarray(pressure_MPa, dtype=float)
    p = p[np.isfinite(p)]
    mean = float(np.mean(p)) if p.size else float("nan")
    se = _noise_rms(p) / np.sqrt(max(p.size, 1))
    tol = 3.0 * se + regulator_resolution_MPa + min(_step(p), 0.01)
    return LabelCheck(run, float(nominal_MPa), mean, float(tol))


def check_labels(
    items: Iterable[tuple[str, float, np.ndarray]],
    regulator_resolution_MPa: float = REGULATOR_RESOLUTION_MPa,
) -> list[LabelCheck]:
    """:func:`check_label` of each (run label, nominal MPa, measured pressure MPa)."""
    return [check_label(r, n, p, regulator_resolution_MPa) for r, n, p in items]


def label_warning(checks: Sequence[LabelCheck], what: str = "the pressure laws") -> str:
    """One line for the runs whose label is offset ("" when none is), e.g. "3 runs: measured
    mean differs from the nominal by 12–37 kPa (...)"."""
    off = [c for c in checks if c.offset]
    if not off:
        return ""
    kpa = sorted(abs(1000.0 * c.offset_MPa) for c in off)
    span = f"{kpa[0]:.1f} kPa" if len(kpa) == 1 else f"{kpa[0]:.1f}–{kpa[-1]:.1f} kPa"
    names = ", ".join(f"{c.run} ({1000.0 * c.offset_MPa:+.1f})" for c in off[:6])
    more = f" and {len(off) - 6} more" if len(off) > 6 else ""
    return (
        f"{len(off)} run{'s' if len(off) > 1 else ''}: measured mean pressure differs from "
        f"the nominal by {span} ({names}{more}), beyond the gauge noise and the regulator's "
        f"resolution; {what} use the nominal value — give --pressure measured to use each "
        "run's measured mean instead"
    )
