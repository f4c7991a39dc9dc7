"""The simulated rig's truth file: every physical parameter of the rig, in TOML.

A truth file is what the simulated rig *really* is — muscle characteristic, braid friction,
cylinder, regulators, sensors — plus the hidden effects of the catalogue (pmalab.identify.effects), each
switchable in ``[effects.<name>]`` with ``enabled`` and its physical size.  Identification
never reads it; tests and benchmarks use it to know the right answer.

Units are in the field names or documented in :data:`SCHEMA` (mm, N, MPa, s, ms, kg, cm³).
Sign conventions (docs/explanation/physics.md): x = contraction in mm (positive = shorter than the nominal
length), force = tension in N.

Every field has a default (``data/truth/default.toml`` spells them all out, every effect
off), so a truth file only needs what differs.  Unknown sections or keys, wrong types and
out-of-range values are errors: :func:`load_truth` reports one line per mistake, naming the
file and the field, in a single :class:`~pmalab.errors.ConfigError`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from pmalab.config import load_toml, unknown_keys
from pmalab.errors import ConfigError
from pmalab.paths import TRUTH_DIR, shipped, shipped_hint

DEFAULT_TRUTH = TRUTH_DIR / "default.toml"

#: effect ids of the catalogue ↔ section names of the truth file
EFFECT_SECTIONS: dict[str, str] = {
    "viscous-friction": "viscous_friction",
    "asymmetric-hysteresis": "asymmetric_hysteresis",
    "nonlinear-stiffness": "nonlinear_stiffness",
    "pressure-variation": "pressure_variation",
    "sensor-delay": "sensor_delay",
    "inertia": "inertia",
    "sensor-drift": "sensor_drift",
}


@dataclass(frozen=True)
class Field:
    """One scalar (or list of floats) field: default, allowed range and a short doc."""

    default: Any
    lo: float | None = None
    hi: float | None = None
    lo_open: bool = False  # True: value must be > lo (strictly)
    doc: str = ""
    kind: str = "float"  # float | bool | list | int


F = Field

#: section → field → Field.  Effects live under "effects.<name>".
SCHEMA: dict[str, dict[str, Field]] = {
    "muscle": {
        "nominal_length_mm": F(120.0, 0.0, None, True, "relaxed length L0 (mm)"),
        "max_force_N": F(1500.0, 0.0, None, True, "tension at x = 0 and reference pressure (N)"),
        "reference_pressure_MPa": F(0.6, 0.0, None, True, "pressure of max_force_N (MPa)"),
        "threshold_pressure_MPa": F(0.035, 0.0, 0.2, False, "no force below this pressure (MPa)"),
        "force_pressure_curvature": F(
            0.1, -0.5, 0.5, False, "F0(p) = Fmax·((1−β)q + βq²), q = (p−p_th)/(p_ref−p_th)"
        ),
        "max_contraction_mm": F(
            30.0, 0.0, None, True, "free contraction at the reference pressure (mm)"
        ),
        "contraction_pressure_scale": F(
            0.35, 0.0, None, True, "x_max(p) ∝ 1 − exp(−q/scale) (dimensionless)"
        ),
        "stretch_stiffness_N_per_mm": F(
            250.0, 0.0, None, False, "extra stiffness when stretched beyond nominal (x < 0)"
        ),
        "max_pressure_MPa": F(
            0.6, 0.0, None, True, "rated pressure: a higher supply is outside the envelope"
        ),
        "stiffness_drift_percent_per_hour": F(
            0.0,
            -1000.0,
            1000.0,
            False,
            "slow change of the muscle's stiffness over its hours of cycling (fatigue, "
            "creep; % of its switch-on stiffness per hour of rig time, negative = softening): "
            "k(t) = k0·(1 + r·t), the tension at x = 0 unchanged",
        ),
    },
    "friction": {
        # braid/bladder friction as a Maxwell-slip model (parallel elasto-plastic elements)
        "slip_force_N": F(
            60.0, 0.0, None, False, "total slip force (loop half-width) at p_ref (N)"
        ),
        "pressure_curvature": F(0.2, -0.5, 1.0, False, "f(p) = f_ref·((1−γ)q + γq²)"),
        "presliding_mm": F(
            [0.3, 1.0, 2.5, 5.0], 0.0, None, True, "element slip displacements (mm)", "list"
        ),
        "weights": F(
            [0.35, 0.3, 0.2, 0.15], 0.0, None, False, "share of each element (normalised)", "list"
        ),
        "presliding_pressure_exponent": F(
            0.0,
            -1.0,
            3.0,
            False,
            "slip displacements × q**a: a > 0 makes slip forces rise faster than stiffnesses",
        ),
    },
    "cylinder": {
        "bore_mm": F(50.0, 0.0, None, True, "piston diameter (mm): force = p·π·bore²/4"),
        "moving_mass_kg": F(2.0, 0.0, None, True, "piston + rod + sled (kg)"),
        "coulomb_N": F(15.0, 0.0, None, False, "seal Coulomb friction (N)"),
        "stiction_N": F(18.0, 0.0, None, False, "seal breakaway friction (N), ≥ coulomb_N"),
        "stribeck_velocity_mm_s": F(5.0, 0.0, None, True, "Stribeck velocity (mm/s)"),
        "viscous_N_s_per_mm": F(0.5, 0.0, None, False, "seal viscous friction (N·s/mm)"),
        "smoothing_velocity_mm_s": F(0.05, 0.0, None, True, "tanh smoothing of sign(v) (mm/s)"),
        "stroke_min_mm": F(-6.0, None, None, False, "end stop, cylinder fully extended (x, mm)"),
        "stroke_max_mm": F(40.0, None, None, False, "end stop, cylinder fully retracted (x, mm)"),
        "stop_stiffness_N_per_mm": F(5000.0, 0.0, None, True, "end-stop stiffness (N/mm)"),
        "stop_damping_N_s_per_mm": F(20.0, 0.0, None, False, "end-stop damping (N·s/mm)"),
    },
    "regulator": {
        # ITV1050-class proportional regulator driving the cylinder
        "max_pressure_MPa": F(0.9, 0.0, None, True, "range 0..max (MPa)"),
        "time_constant_ms": F(70.0, 0.0, None, False, "first-order lag (ms)"),
        "dead_time_ms": F(15.0, 0.0, 500.0, False, "pure delay of the command (ms)"),
        "bits": F(10, 1, 24, False, "setpoint quantization (bits over the range)", "int"),
    },
    "supply": {
        # the muscle's pressure supply with every effect off
        "time_constant_s": F(
            0.3, 0.0, None, True, "first-order settling of the muscle pressure (s)"
        ),
    },
    "sensors": {
        "position_noise_mm": F(0.015, 0.0, None, False, "rms noise (mm)"),
        "position_resolution_mm": F(0.001, 0.0, None, False, "quantization step (mm), 0 = none"),
        "position_time_constant_ms": F(1.0, 0.0, None, False, "first-order lag (ms)"),
        "force_noise_N": F(0.7, 0.0, None, False, "rms noise (N)"),
        "force_resolution_N": F(0.1, 0.0, None, False, "quantization step (N)"),
        "force_time_constant_ms": F(1.0, 0.0, None, False, "first-order lag (ms)"),
        "pressure_noise_MPa": F(0.001, 0.0, None, False, "rms noise of both pressure gauges (MPa)"),
        "pressure_resolution_MPa": F(0.001, 0.0, None, False, "quantization step (MPa)"),
        "pressure_time_constant_ms": F(5.0, 0.0, None, False, "first-order lag (ms)"),
    },
    "integrator": {
        "max_step_ms": F(
            0.25, 0.0, 1.0, True, "largest sub-step of the mechanical integrator (ms)"
        ),
    },
    "effects.viscous_friction": {
        "enabled": F(False, kind="bool"),
        "c": F(0.0, 0.0, None, False, "rate-dependent braid friction (N·s/mm), opposing motion"),
    },
    "effects.asymmetric_hysteresis": {
        "enabled": F(False, kind="bool"),
        "stretch_friction_factor": F(
            1.0, 0.0, None, True, "slip force while stretching ÷ slip force while contracting"
        ),
        "stretch_presliding_factor": F(
            1.0, 0.0, None, True, "pre-sliding displacement while stretching ÷ while contracting"
        ),
        "friction_position_gain": F(
            0.0, -0.9, 0.9, False, "slip force × (1 + g·(1 − 2x/x_max)): wide loop end ≠ narrow end"
        ),
    },
    "effects.nonlinear_stiffness": {
        "enabled": F(False, kind="bool"),
        "curvature": F(
            0.0, -0.9, 0.9, False, "F_s = F0·(1−s)(1−κs), s = x/x_max(p) (dimensionless κ)"
        ),
    },
    "effects.pressure_variation": {
        "enabled": F(False, kind="bool"),
        "volume_cm3": F(80.0, 0.0, None, True, "muscle + tubing volume at x = 0 (cm³)"),
        "dvolume_cm3_per_mm": F(
            0.0, 0.0, None, False, "volume growth per mm of contraction (cm³/mm)"
        ),
        "regulator_time_constant_s": F(
            1.0, 0.0, None, True, "slow (manual) regulator time constant (s)"
        ),
    },
    "effects.sensor_delay": {
        "enabled": F(False, kind="bool"),
        "position_ms": F(0.0, 0.0, 200.0, False, "pure delay of the position channel (ms)"),
        "force_ms": F(0.0, 0.0, 200.0, False, "pure delay of the force channel (ms)"),
        "muscle_pressure_ms": F(0.0, 0.0, 200.0, False, "pure delay of the muscle pressure (ms)"),
        "cylinder_pressure_ms": F(
            0.0, 0.0, 200.0, False, "pure delay of the cylinder pressure (ms)"
        ),
    },
    "effects.inertia": {
        "enabled": F(False, kind="bool"),
        "mass_kg": F(0.0, 0.0, None, False, "moving mass between muscle and load cell (kg)"),
    },
    # ---- off-catalogue effects: no identification effect models them; the diagnosis must
    # not claim a catalogue effect for them (look-alikes of slow catalogue effects)
    "effects.conditioning": {
        "enabled": F(False, kind="bool"),
        "stiffening_percent": F(
            0.0,
            0.0,
            100.0,
            False,
            "bladder conditioning (Mullins-like): the virgin muscle's tension is higher by "
            "this % and softens as it is stretched: F0·(1 + a·exp(−S/S0)), S the path (mm) "
            "the muscle has moved since switch-on",
        ),
        "path_mm": F(200.0, 0.0, None, True, "path S0 (mm) over which the softening decays"),
    },
    "effects.warming": {
        "enabled": F(False, kind="bool"),
        "stiffness_change_percent": F(
            0.0,
            -50.0,
            50.0,
            False,
            "stiffness change as the muscle warms (%): k(t) = k0·(1 + b·(1 − exp(−t/τ))), "
            "t the rig time since switch-on, the tension at x = 0 unchanged",
        ),
        "time_constant_s": F(60.0, 0.0, None, True, "warming time constant τ (s)"),
    },
    "effects.breakaway": {
        "enabled": F(False, kind="bool"),
        "spike_N": F(
            0.0,
            0.0,
            None,
            False,
            "braid stiction breaking away at each reversal: a tension spike of this size "
            "(N), raised while stretching and lowered while contracting",
        ),
        "decay_ms": F(30.0, 0.0, None, True, "decay time of the spike (ms)"),
    },
    "effects.mains_pickup": {
        "enabled": F(False, kind="bool"),
        "amplitude_N": F(0.0, 0.0, None, False, "mains hum on the load-cell reading (N, peak)"),
        "frequency_Hz": F(50.0, 0.0, None, True, "mains frequency (Hz)"),
    },
    "effects.sensor_drift": {
        "enabled": F(False, kind="bool"),
        "force_N_per_min": F(0.0, None, None, False, "load-cell zero drift (N/min)"),
        "position_mm_per_min": F(0.0, None, None, False, "position zero drift (mm/min)"),
        "tare_each_run": F(
            False,
            kind="bool",
            doc="true: the zeros are tared as each run's muscle pressure is requested, so the "
            "drift grows from 0 in every run; false: it grows from switch-on, carried over",
        ),
    },
}


class Truth:
    """A validated truth file: ``truth.section("muscle")["max_force_N"]`` etc.

    Attribute-style access is provided for the common sections:
    ``truth.muscle``, ``truth.friction``, ``truth.effects["viscous_friction"]``.
    """

    def __init__(self, values: dict[str, dict[str, Any]], source: str) -> None:
        self.values = values
        self.source = source

    def __repr__(self) -> str:
        return f"Truth({self.source!r}, effects={self.enabled_effects()})"

    def section(self, name: str) -> dict[str, Any]:
        return self.values[name]

    def __getattr__(self, name: str) -> dict[str, Any]:
        values = self.__dict__.get("values", {})
        if name in values:
            return values[name]
        raise AttributeError(name)

    @property
    def effects(self) -> dict[str, dict[str, Any]]:
        return {k.split(".", 1)[1]: v for k, v in self.values.items() if k.startswith("effects.")}

    def effect(self, name: str) -> dict[str, Any] | None:
        """The parameters of effect ``name`` (section name or DESIGN effect id) if enabled."""
        name = EFFECT_SECTIONS.get(name, name)
        sec = self.values[f"effects.{name}"]
        return sec if sec["enabled"] else None

    def enabled_effects(self) -> list[str]:
        """DESIGN effect ids of the enabled effects."""
        return [
            eid for eid, sec in EFFECT_SECTIONS.items() if self.values[f"effects.{sec}"]["enabled"]
        ]

    def with_changes(self, **changes: dict[str, Any]) -> Truth:
        """A copy with sections updated, e.g. ``with_changes(**{"effects.inertia": {...}})``.

        Section names use dots; pass them through ``**{...}``.  Values are validated.
        """
        raw = {k: dict(v) for k, v in self.values.items()}
        for sec, upd in changes.items():
            if sec not in raw:
                raise ConfigError(f"{self.source}: {sec}: unknown section")
            raw[sec].update(upd)
        return validate(_nest(raw), self.source)

    def to_dict(self) -> dict[str, dict[str, Any]]:
        return {k: dict(v) for k, v in self.values.items()}


def _nest(flat: dict[str, dict[str, Any]]) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for sec, vals in flat.items():
        node = out
        for part in sec.split("."):
            node = node.setdefault(part, {})
        node.update(vals)
    return out


def _check(value: Any, f: Field, where: str) -> tuple[Any, str | None]:
    """Return (converted value, error text or None)."""
    if f.kind == "bool":
        if not isinstance(value, bool):
            return value, f"{where}: must be true or false"
        return value, None
    if f.kind == "list":
        if not isinstance(value, list) or not value:
            return value, f"{where}: must be a non-empty list of numbers"
        out = []
        for v in value:
            if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
                return value, f"{where}: must be a non-empty list of numbers"
            err = _range_error(float(v), f)
            if err:
                return value, f"{where}: every element {err}"
            out.append(float(v))
        return out, None
    if isinstance(value, bool) or not isinstance(value, int | float):
        return value, f"{where}: must be a number"
    if f.kind == "int":
        if not isinstance(value, int):
            return value, f"{where}: must be an integer"
        err = _range_error(float(value), f)
        return int(value), (f"{where}: {err}" if err else None)
    v = float(value)
    if not math.isfinite(v):
        return value, f"{where}: must be a finite number"
    err = _range_error(v, f)
    return v, (f"{where}: {err}" if err else None)


def _range_error(v: float, f: Field) -> str | None:
    if f.lo is not None:
        if f.lo_open and not v > f.lo:
            return f"must be > {f.lo:g}"
        if not f.lo_open and v < f.lo:
            return f"must be ≥ {f.lo:g}"
    if f.hi is not None and v > f.hi:
        return f"must be ≤ {f.hi:g}"
    return None


def validate(doc: dict[str, Any], source: str) -> Truth:
    """Validate a parsed truth document; raise one ConfigError listing every mistake."""
    errors: list[str] = []
    values: dict[str, dict[str, Any]] = {}
    given: dict[str, dict[str, Any]] = {}

    for key, val in doc.items():
        if key == "effects":
            if not isinstance(val, dict):
                errors.append(f"{source}: effects: must be a table")
                continue
            for eff, eval_ in val.items():
                sec = f"effects.{eff}"
                if sec not in SCHEMA:
                    known = ", ".join(
                        sorted(s.split(".", 1)[1] for s in SCHEMA if s.startswith("effects."))
                    )
                    errors.append(f"{source}: effects.{eff}: unknown effect (known: {known})")
                elif not isinstance(eval_, dict):
                    errors.append(f"{source}: {sec}: must be a table")
                else:
                    given[sec] = eval_
        elif key in SCHEMA:
            if not isinstance(val, dict):
                errors.append(f"{source}: {key}: must be a table")
            else:
                given[key] = val
        else:
            known = ", ".join(s for s in SCHEMA if not s.startswith("effects.")) + ", effects"
            errors.append(f"{source}: {key}: unknown section (known: {known})")

    for sec, fields in SCHEMA.items():
        vals: dict[str, Any] = {}
        sec_given = given.get(sec, {})
        for name in unknown_keys(sec_given, fields):
            errors.append(f"{source}: {sec}.{name}: unknown key (known: {', '.join(fields)})")
        for name, f in fields.items():
            if name in sec_given:
                v, err = _check(sec_given[name], f, f"{source}: {sec}.{name}")
                if err:
                    errors.append(err)
                vals[name] = v
            else:
                vals[name] = list(f.default) if isinstance(f.default, list) else f.default
        values[sec] = vals

    if not errors:
        errors.extend(_cross_checks(values, source))
    if errors:
        raise ConfigError("\n".join(errors))
    return Truth(values, source)


def _cross_checks(v: dict[str, dict[str, Any]], source: str) -> list[str]:
    errs = []
    fr = v["friction"]
    if len(fr["presliding_mm"]) != len(fr["weights"]):
        errs.append(
            f"{source}: friction.weights: must have as many elements as friction.presliding_mm"
        )
    elif len(fr["weights"]) > 8:
        errs.append(f"{source}: friction.presliding_mm: at most 8 elements")
    elif sum(fr["weights"]) <= 0:
        errs.append(f"{source}: friction.weights: must not all be 0")
    m = v["muscle"]
    if m["threshold_pressure_MPa"] >= m["reference_pressure_MPa"]:
        errs.append(
            f"{source}: muscle.threshold_pressure_MPa: must be < muscle.reference_pressure_MPa"
        )
    c = v["cylinder"]
    if c["stiction_N"] < c["coulomb_N"]:
        errs.append(f"{source}: cylinder.stiction_N: must be ≥ cylinder.coulomb_N")
    if c["stroke_min_mm"] >= c["stroke_max_mm"]:
        errs.append(f"{source}: cylinder.stroke_min_mm: must be < cylinder.stroke_max_mm")
    return errs


def load_truth(path: str | Path | None = None) -> Truth:
    """Read and validate a truth TOML file (``None`` → ``data/truth/default.toml``).

    A shipped truth is found by name (``hidden-viscous-friction``, ``subtle/clean``) or by
    its clone path (``data/truth/hidden-viscous-friction.toml``) from any directory.

    Raises :class:`ConfigError` with one line per mistake, each naming the file and field,
    e.g. ``truth.toml: effects.viscous_friction.c: must be ≥ 0``.
    """
    p = DEFAULT_TRUTH if path is None else shipped(path, TRUTH_DIR)
    source = str(path) if path is not None else str(p)
    doc, _ = load_toml(p, "truth file", where=source, hint=shipped_hint(TRUTH_DIR, "truths"))
    return validate(doc, source)


def default_truth() -> Truth:
    """All defaults, every effect off (same as ``data/truth/default.toml``)."""
    return validate({}, "<defaults>")
