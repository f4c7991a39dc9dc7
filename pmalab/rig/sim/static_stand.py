"""A simulated static test stand: a muscle held at a length (isometric), loaded with a weight
(isotonic), held at a pressure (isobaric) or moved in both (free), its pressure ramped or
cycled by a regulator — the characterization every PMA paper starts with.

Truth (written apart from the identification models, imports nothing from ``identify``):

* **static map**: the geometric model of Chou & Hannaford (1996, "Measurement and modeling of
  McKibben pneumatic artificial muscles", IEEE Trans. Robotics and Automation 12(1):90–102)
  from virtual work on an inextensible braid, F = (π·D0²·p/4)·(3·cos²θ − 1) with D0 the
  diameter at θ = 90°, written with the initial braid angle θ0, initial diameter Di = D0·sinθ0
  and length L0 (cos θ = cos θ0·(1 − k·ε), ε = x/L0), and Tondu & Lopez's end-effect factor
  k ≥ 1 (2000, "Modeling and control of McKibben artificial muscle robot actuators", IEEE
  Control Systems Magazine 20(2):15–38: the capped ends stay narrow, so the cylindrical part
  contracts k times the mean strain)::

      F_s(x, p) = (π·Di²·p/4)·[3·(1 − k·ε)²/tan²θ0 − 1/sin²θ0] + F_off

  (p MPa = N/mm², Di mm → N);
* **pressure-domain hysteresis**: strand-on-strand friction in the braid (Tondu 2012's review
  attributes the loop to it) seen as a Maxwell-slip set of elements driven by the pressure
  (element i deflects with the pressure by at most δ_i MPa, then slips; h = −W·Σ w_i·z_i/δ_i):
  force lower while inflating than while venting at the same pressure, a loop of half-width
  W (N) once every element slips — or, with ``pressure_friction_reference_MPa`` = p_ref > 0,
  W·p/p_ref (friction proportional to the contact pressure, as in Tondu & Lopez's model:
  the loop pinches at p = 0);
* optional **position-domain hysteresis** of the same kind driven by the contraction (mm), for
  isobaric and free tests;
* a first-order pressure regulator, sensor noise and quantization, and (the real stand-ins'
  quirk) a data logger that stamps time in whole milliseconds and writes one sample twice.

Units: x contraction mm (positive = shorter), force tension N, pressure MPa gauge, time s.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from pmalab.config import load_toml, unknown_keys
from pmalab.errors import ConfigError
from pmalab.paths import TRUTH_DIR, shipped
from pmalab.runfile import Run

STATIC_TRUTH_DIR = TRUTH_DIR / "static"


@dataclass(frozen=True)
class StaticTruth:
    """Everything the simulated stand really is (see the module docstring for the equations)."""

    #: initial (relaxed) braid angle θ0 (degrees from the muscle's axis)
    braid_angle_deg: float = 22.0
    #: initial (relaxed) outer diameter Di (mm)
    diameter_mm: float = 10.0
    #: initial (relaxed) active length L0 (mm)
    length_mm: float = 200.0
    #: end-effect factor k (−, ≥ 1: the cylindrical part contracts k·ε)
    end_effect: float = 1.5
    #: force offset (N): a load cell's pretension
    offset_N: float = 0.0
    #: pressure-domain loop half-width W (N)
    pressure_friction_N: float = 6.0
    #: > 0: the friction grows with the contact pressure, W·p/p_ref (Tondu & Lopez's friction
    #: is proportional to the pressure), so the loop pinches at p = 0; 0: constant W
    pressure_friction_reference_MPa: float = 0.0
    #: pressure-domain elements' slip ranges δ_i (MPa) and weights
    pressure_presliding_MPa: tuple[float, ...] = (0.01, 0.03, 0.06, 0.1)
    pressure_weights: tuple[float, ...] = (0.3, 0.3, 0.25, 0.15)
    #: position-domain loop half-width (N) and elements (mm): 0 = none
    position_friction_N: float = 0.0
    position_presliding_mm: tuple[float, ...] = (0.3, 1.0, 2.5)
    position_weights: tuple[float, ...] = (0.4, 0.35, 0.25)
    #: pressure regulator's first-order time constant (s)
    regulator_time_constant_s: float = 0.05
    #: sensors: rms noise and quantization
    force_noise_N: float = 0.7
    force_resolution_N: float = 0.01
    pressure_noise_MPa: float = 0.001
    pressure_resolution_MPa: float = 0.0001
    position_noise_mm: float = 0.015
    position_resolution_mm: float = 0.001
    #: a file name or "" (in-memory)
    source: str = field(default="", compare=False)

    @property
    def max_contraction_mm(self) -> float:
        """Free contraction at any pressure (F_s = 0 without offset): 1 − k·ε = cos θ0/√3."""
        th = math.radians(self.braid_angle_deg)
        return (1.0 - math.cos(th) / math.sqrt(3.0)) / self.end_effect * self.length_mm

    def static_force(self, x: np.ndarray | float, p: np.ndarray | float) -> np.ndarray:
        """F_s(x, p) in N (x mm contraction, p MPa)."""
        th = math.radians(self.braid_angle_deg)
        eps = np.asarray(x, dtype=float) / self.length_mm
        area = math.pi * self.diameter_mm**2 / 4.0
        shape = 3.0 * (1.0 - self.end_effect * eps) ** 2 / math.tan(th) ** 2
        shape = shape - 1.0 / math.sin(th) ** 2
        return area * np.asarray(p, dtype=float) * shape + self.offset_N


#: field → (lo, hi, doc) of a static truth file (``[muscle]``, ``[friction]``, ``[sensors]``)
_FIELDS: dict[str, dict[str, tuple[float, float]]] = {
    "muscle": {
        "braid_angle_deg": (5.0, 54.0),
        "diameter_mm": (1.0, 100.0),
        "length_mm": (10.0, 2000.0),
        "end_effect": (1.0, 3.0),
        "offset_N": (-1000.0, 1000.0),
    },
    "friction": {
        "pressure_friction_N": (0.0, 500.0),
        "pressure_friction_reference_MPa": (0.0, 1.2),
        "pressure_presliding_MPa": (1e-5, 1.0),
        "pressure_weights": (0.0, 1.0),
        "position_friction_N": (0.0, 500.0),
        "position_presliding_mm": (1e-4, 50.0),
        "position_weights": (0.0, 1.0),
    },
    "regulator": {"regulator_time_constant_s": (0.0, 5.0)},
    "sensors": {
        "force_noise_N": (0.0, 100.0),
        "force_resolution_N": (0.0, 10.0),
        "pressure_noise_MPa": (0.0, 0.1),
        "pressure_resolution_MPa": (0.0, 0.01),
        "position_noise_mm": (0.0, 5.0),
        "position_resolution_mm": (0.0, 1.0),
    },
}


def load_static_truth(spec: str | Path | None = None) -> StaticTruth:
    """A static stand's truth from TOML (a path, or a shipped name such as ``geometric``).

    Sections ``[muscle]``, ``[friction]``, ``[regulator]``, ``[sensors]`` with the fields of
    :class:`StaticTruth`; unknown keys and out-of-range values are one
    :class:`~pmalab.errors.ConfigError` naming the file and the field.
    """
    if spec is None:
        return StaticTruth()
    path = shipped(spec, STATIC_TRUTH_DIR)
    doc, _ = load_toml(path, "static truth file")
    errors: list[str] = []
    values: dict[str, Any] = {}
    for sec in unknown_keys(doc, _FIELDS):
        errors.append(f"{path}: unknown section [{sec}] (known: {', '.join(_FIELDS)})")
    for sec, fields in _FIELDS.items():
        table = doc.get(sec, {})
        for key in unknown_keys(table, fields):
            errors.append(f"{path}: [{sec}] unknown field '{key}'")
        for key, (lo, hi) in fields.items():
            if key not in table:
                continue
            v = table[key]
            items = v if isinstance(v, list) else [v]
            if not all(isinstance(i, int | float) and not isinstance(i, bool) for i in items):
                errors.append(f"{path}: [{sec}] {key}: not a number")
                continue
            if not all(lo <= float(i) <= hi for i in items):
                errors.append(f"{path}: [{sec}] {key}: {v} outside [{lo:g}, {hi:g}]")
                continue
            values[key] = tuple(float(i) for i in v) if isinstance(v, list) else float(v)
    for kind in ("pressure", "position"):
        d = values.get(f"{kind}_presliding_{'MPa' if kind == 'pressure' else 'mm'}")
        w = values.get(f"{kind}_weights")
        if (d is None) != (w is None) or (d is not None and w is not None and len(d) != len(w)):
            errors.append(
                f"{path}: [friction] {kind}_presliding and {kind}_weights: one per element"
            )
    if errors:
        raise ConfigError("\n".join(errors))
    return replace(StaticTruth(), source=str(path), **values)


class _Slip:
    """Maxwell-slip elements driven by one input: total slip force W (N), ranges δ_i."""

    def __init__(self, W: float, delta: tuple[float, ...], weights: tuple[float, ...]) -> None:
        self.W = float(W)
        self.delta = np.asarray(delta, dtype=float)
        w = np.asarray(weights, dtype=float)
        self.w = w / w.sum()
        self.z = np.zeros_like(self.delta)

    def start(self, direction: float) -> None:
        """Every element slipped as after a long move in ``direction`` (+1 rising)."""
        self.z = direction * self.delta

    def step(self, du: float) -> float:
        """Advance by du; h (N): −W·Σ w_i·z_i/δ_i (lower while the input rises)."""
        self.z = np.clip(self.z + du, -self.delta, self.delta)
        return -self.W * float(np.sum(self.w * self.z / self.delta))


def _quantize(v: np.ndarray, step: float) -> np.ndarray:
    return np.round(v / step) * step if step > 0 else v


@dataclass
class StandRecord:
    """What one test on the stand measured (and the truth behind it)."""

    time: np.ndarray  # s
    position: np.ndarray  # mm (measured; the held value for an isometric test)
    force: np.ndarray  # N
    pressure: np.ndarray  # MPa (measured)
    branch: np.ndarray  # 1 pressurising, 2 venting (from the command's direction)
    true_force: np.ndarray
    true_pressure: np.ndarray
    true_position: np.ndarray
    test_type: str
    held: float | None  # held contraction (mm) or load (N)

    def to_run(self, name: str, **attrs: Any) -> Run:
        """The record as a contract run (test type and held value as attrs)."""
        a: dict[str, Any] = {
            "test_type": self.test_type,
            "muscle_pressure_MPa": float(np.mean(self.pressure)),
            "waveform": attrs.pop("waveform", "ramp"),
            "frequency_Hz": attrs.pop("frequency_Hz", None),
            "sample_rate_Hz": float(1.0 / np.median(np.diff(self.time))),
            "source": "simulated static stand",
            "status": "completed",
            "role": attrs.pop("role", "identification"),
        }
        if self.test_type == "isometric" and self.held is not None:
            a["held_position_mm"] = float(self.held)
        if self.test_type == "isotonic" and self.held is not None:
            a["load_N"] = float(self.held)
        if self.test_type == "isobaric":
            a["muscle_pressure_MPa"] = float(np.median(self.true_pressure))
        a.update(attrs)
        return Run(
            name=name,
            time=self.time,
            position=self.position,
            force=self.force,
            muscle_pressure=self.pressure,
            branch=self.branch,
            attrs=a,
        )


def pressure_command(
    t: np.ndarray, p_max: float, period_s: float, waveform: str = "ramp", p_min: float = 0.0
) -> np.ndarray:
    """The regulator's command (MPa): ``ramp`` (triangle p_min → p_max → p_min per period),
    ``steps`` (the triangle held in 8 stairs each way) or ``sine``."""
    phase = (t / period_s) % 1.0
    tri = np.where(phase < 0.5, 2.0 * phase, 2.0 - 2.0 * phase)
    if waveform == "steps":
        tri = np.floor(tri * 8.0 + 0.5) / 8.0
    elif waveform == "sine":
        tri = 0.5 * (1.0 - np.cos(2.0 * np.pi * phase))
    elif waveform != "ramp":
        raise ConfigError(f"pressure waveform: unknown '{waveform}' (ramp, steps, sine)")
    return p_min + (p_max - p_min) * tri


def run_test(
    truth: StaticTruth,
    test_type: str,
    *,
    held_mm: float = 0.0,
    load_N: float = 200.0,
    pressure_MPa: float = 0.4,
    p_max: float = 0.62,
    p_min: float = 0.0,
    period_s: float = 20.0,
    cycles: float = 1.0,
    waveform: str = "ramp",
    stroke_mm: float = 10.0,
    x_period_s: float = 6.0,
    sample_rate_Hz: float = 500.0,
    seed: int = 0,
) -> StandRecord:
    """One test on the stand.

    Parameters
    ----------
    test_type
        ``isometric`` (length held at ``held_mm``, pressure by ``waveform`` between ``p_min``
        and ``p_max`` over ``period_s``), ``isotonic`` (a ``load_N`` weight, the same
        pressure cycle, the length it settles at measured), ``isobaric`` (pressure held at
        ``pressure_MPa``, the length a sine about ``held_mm`` of ``stroke_mm`` peak to peak
        over ``x_period_s``) or ``free`` (the isometric pressure cycle and the isobaric
        length sine at once).
    cycles
        Pressure (or length) periods recorded.
    seed
        The sensor noise's seed.

    Returns
    -------
    StandRecord
        Measured channels and the truth behind them.
    """
    rng = np.random.default_rng(seed)
    period = x_period_s if test_type == "isobaric" else period_s
    n = round(cycles * period * sample_rate_Hz) + 1
    t = np.arange(n) / sample_rate_Hz
    if test_type == "isobaric":
        cmd = np.full(n, float(pressure_MPa))
    else:
        cmd = pressure_command(t, p_max, period_s, waveform, p_min)
    # first-order regulator, exact for a piecewise-constant command
    tau = truth.regulator_time_constant_s
    a = math.exp(-1.0 / (sample_rate_Hz * tau)) if tau > 0 else 0.0
    p = np.empty(n)
    p[0] = cmd[0]
    for k in range(1, n):
        p[k] = a * p[k - 1] + (1.0 - a) * cmd[k]
    if test_type in ("isobaric", "free"):
        x = held_mm + 0.5 * stroke_mm * np.sin(2.0 * np.pi * t / x_period_s)
    else:
        x = np.full(n, float(held_mm))
    hp = _Slip(truth.pressure_friction_N, truth.pressure_presliding_MPa, truth.pressure_weights)
    hx = _Slip(truth.position_friction_N, truth.position_presliding_mm, truth.position_weights)
    ref = truth.pressure_friction_reference_MPa
    scale = p / ref if ref > 0 else np.ones(n)  # friction ∝ contact pressure (or constant)
    hp.start(-1.0)  # the muscle was vented before the test
    hx.start(-1.0)
    F = np.empty(n)
    if test_type == "isotonic":
        # quasi-static: the length where the muscle's tension carries the load
        xk = _solve_length(truth, p[0], load_N - hp.step(0.0) * scale[0] - hx.step(0.0), held_mm)
        for k in range(n):
            h_p = (hp.step(p[k] - p[k - 1]) if k else hp.step(0.0)) * scale[k]
            target = load_N - h_p
            x_new = _solve_length(truth, p[k], target - hx.step(0.0), xk)
            h_x = hx.step(x_new - xk)
            xk = _solve_length(truth, p[k], target - h_x, x_new)
            x[k] = xk
            F[k] = load_N
    else:
        for k in range(n):
            h_p = (hp.step(p[k] - p[k - 1]) if k else hp.step(0.0)) * scale[k]
            h_x = hx.step(x[k] - x[k - 1]) if k else hx.step(0.0)
            F[k] = float(truth.static_force(x[k], p[k])) + h_p + h_x
    rising = np.gradient(cmd) >= 0.0
    branch = np.where(rising, 1.0, 2.0)
    f_meas = _quantize(F + rng.normal(0.0, truth.force_noise_N, n), truth.force_resolution_N)
    p_meas = _quantize(
        p + rng.normal(0.0, truth.pressure_noise_MPa, n), truth.pressure_resolution_MPa
    )
    if test_type == "isometric":
        x_meas = x.copy()  # the held value, as the user gives it
    else:
        x_meas = _quantize(
            x + rng.normal(0.0, truth.position_noise_mm, n), truth.position_resolution_mm
        )
    held = (
        float(held_mm)
        if test_type == "isometric"
        else (float(load_N) if test_type == "isotonic" else None)
    )
    return StandRecord(t, x_meas, f_meas, p_meas, branch, F, p, x, test_type, held)


def _solve_length(truth: StaticTruth, p: float, target_N: float, x0: float) -> float:
    """The contraction (mm) where F_s(x, p) = target (bisection; F_s falls with x)."""
    x_hi = truth.max_contraction_mm
    lo, hi = -0.2 * truth.length_mm, x_hi
    f = lambda x: float(truth.static_force(x, p)) - target_N  # noqa: E731
    if f(lo) < 0.0:
        return lo
    if f(hi) > 0.0:
        return hi
    x = min(max(x0, lo), hi)
    for _ in range(60):
        fx = f(x)
        if f(lo) * fx <= 0:
            hi = x
        else:
            lo = x
        x = 0.5 * (lo + hi)
        if hi - lo < 1e-7:
            break
    return x


def isometric_campaign(
    truth: StaticTruth,
    held_mm: tuple[float, ...] | list[float],
    *,
    seed: int = 0,
    **kw: Any,
) -> list[Run]:
    """One isometric run per held contraction (mm), named ``iso-<x>mm``."""
    return [
        run_test(truth, "isometric", held_mm=x, seed=seed + i, **kw).to_run(f"iso-{x:g}mm")
        for i, x in enumerate(held_mm)
    ]


def write_headerless(record: StandRecord, path: str | Path, *, duplicate_at: int = 9) -> Path:
    """The record as a real isometric logger writes it: no header, tab-separated columns
    force N, pressure kPa, time s (whole milliseconds), state (1 pressurising, 2 venting),
    and one sample written twice (its time stamp repeated) at ``duplicate_at``."""
    t = np.round(record.time, 3)
    rows = np.column_stack([record.force, record.pressure * 1e3, t, record.branch])
    if 0 < duplicate_at < len(rows):
        rows = np.insert(rows, duplicate_at, rows[duplicate_at - 1], axis=0)
    path = Path(path)
    with path.open("w") as fh:
        for r in rows:
            fh.write(f"{r[0]:.3f}\t{r[1]:.2f}\t{r[2]:.3f}\t{int(r[3])}\n")
    return path
