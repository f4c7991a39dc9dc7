"""Protocol files (TOML): isobaric runs and campaigns, validated field by field.

An *isobaric run* holds the muscle at a constant gauge pressure (``muscle_pressure_MPa``)
while the cylinder's proportional regulator is driven with a periodic command of cylinder
pressure (MPa):

    command(t) = envelope(t) · (offset + amplitude · w(2π·f·t))

with ``w`` the unit waveform (sine | triangle | square) phased to start at its minimum
(−1), so a run with ``offset == amplitude`` starts and ends at zero cylinder pressure.
More cylinder pressure stretches the muscle: the contraction x falls and the tension rises.
``envelope`` is a raised-cosine ramp in (0→1 over ``ramp_s``) and out (1→0); the steady
part holds ``cycles`` full periods.  Each run is preceded by ``settle_s`` seconds at the
``preload_MPa`` command (default 0) with the muscle already at its pressure (recorded); the
ramp blends the preload into the waveform.  A preload pulls a muscle taut that the previous
run left slack (after a drop in muscle pressure its free contraction is shorter than where
the sled stands, and nothing moves the sled back until the cylinder pushes).

``magnitude_MPa = M`` is the seeds' shorthand for a command from 0 to M
(``offset = amplitude = M/2``).

File layout::

    [protocol]                 # optional: name, description
    name = "seed-bouc-wen"
    [defaults]                 # optional: any run field, applied to every run/campaign
    cycles = 3
    [[run]]                    # one isobaric run
    name = "ident"
    role = "identification"    # identification | validation (free tag used downstream)
    muscle_pressure_MPa = 0.4762
    waveform = "sine"
    frequency_Hz = 0.15
    magnitude_MPa = 0.35
    [[campaign]]               # lists expand to their cartesian product
    name = "pressure"
    muscle_pressure_MPa = [0.1, 0.2, 0.3]
    waveform = ["sine", "triangle"]
    [[campaign]]               # `pair`: these lists are zipped, not crossed
    name = "levels"
    pair = ["muscle_pressure_MPa", "magnitude_MPa"]
    muscle_pressure_MPa = [0.1, 0.2, 0.4]
    magnitude_MPa = [0.07, 0.20, 0.35]
    waveform = ["sine", "triangle"]

Campaigns.  Every list-valued field (``muscle_pressure_MPa``, ``waveform``,
``frequency_Hz``, ``amplitude_MPa``, ``offset_MPa``, ``magnitude_MPa``, ``muscle``) is one axis of a
cartesian product.  ``pair = [field, field, ...]`` names lists of *equal length* that are
zipped into a single axis instead (the i-th pressure runs with the i-th magnitude); every
other list is still crossed with it.  The second campaign above gives 3 × 2 = 6 runs
(``levels-100kPa-mag70kPa-sine``, ``levels-100kPa-mag70kPa-triangle``, ...), not
3 × 3 × 2.  Lists of unequal length, or a paired field that is not a list, are a
ConfigError.

Campaign run names are ``<name>-<value>-<value>...`` with one value per varying field, in
the order of the list above, a pair's fields together (muscle pressure as ``100kPa``, other pressures as
``amp…kPa``/``off…kPa``/``mag…kPa``, frequency as ``0.15Hz``, waveform by name).  A
``name`` holding ``{field}`` placeholders is a template instead, filled with the same
formatted values and nothing appended: ``name = "pressure-{muscle_pressure_MPa}-tri"``
gives ``pressure-100kPa-tri``, ... (a template must keep the names unique).

On a rig with several muscles (an antagonistic pair) ``muscle = "flexor"`` names the
muscle a run holds isobaric; the other muscle's regulator is driven with the waveform in
the cylinder's place, so it stretches and releases the held one through the joint.

Test types.  ``test_type = "isobaric"`` (the default) is the above.  ``"isometric"`` and
``"isotonic"`` drive the *muscle's* regulator with the waveform instead (the cylinder is
not used): ``offset_MPa``/``amplitude_MPa`` (or ``magnitude_MPa``) are the muscle pressure
command, a triangle is a ramp up and down, ``"steps"`` that triangle held in 8 stairs each
way, a sine a smooth cycle; the run starts (``settle_s``) at the waveform's minimum and
``ramp_s`` defaults to 0.  An isometric run holds ``held_position_mm`` (contraction, mm);
an isotonic run hangs ``load_N`` (N) and measures the length.  ``muscle_pressure_MPa`` is
then the command's mean, recorded, not held.  Only a rig with a commanded muscle
regulator plays them (the runner refuses the rest before anything moves).

Every mistake raises :class:`~pmalab.errors.ConfigError` with one line naming the file
and the field (``file: run[2] 'ident': field 'frequency_Hz': must be > 0``).
"""

from __future__ import annotations

import itertools
import json
import math
import re
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

from pmalab.config import check_keys, parse_toml, read_text
from pmalab.errors import ConfigError
from pmalab.paths import PROTOCOLS_DIR, shipped, shipped_hint

WAVEFORMS = ("sine", "triangle", "square", "steps")
#: test types a protocol can play (the run file's ``test_type``; ``free`` is not playable)
TEST_TYPES = ("isobaric", "isometric", "isotonic")
ROLES = ("identification", "validation", "other")
SAMPLE_RATE_HZ = 500.0
#: the fastest rate a protocol may ask for (a hardware-timed card; a polled rig refuses more
#: in its own file's check)
MAX_SAMPLE_RATE_HZ = 100e3
#: a gauge pressure beyond any PMA rig (muscles are rated 0.6 MPa, regulators 0.9 MPa)
MAX_GAUGE_MPA = 1.2

#: fields a run (or campaign, or [defaults]) may set, with their type and default
_FIELDS: dict[str, tuple[type | tuple[type, ...], Any]] = {
    "role": (str, "identification"),
    "muscle_pressure_MPa": ((int, float), None),
    "waveform": (str, "sine"),
    "frequency_Hz": ((int, float), None),
    "amplitude_MPa": ((int, float), None),
    "offset_MPa": ((int, float), None),
    "magnitude_MPa": ((int, float), None),
    "cycles": ((int, float), 3),
    "ramp_s": ((int, float), 2.0),
    "settle_s": ((int, float), 1.0),
    "preload_MPa": ((int, float), 0.0),
    "square_edge": ((int, float), 0.05),
    "pressure_tolerance_MPa": ((int, float), 0.01),
    "pressure_stable_s": ((int, float), 0.5),
    "pressure_timeout_s": ((int, float), 120.0),
    "description": (str, ""),
    "muscle": (str, ""),
    "test_type": (str, "isobaric"),
    "held_position_mm": ((int, float), None),
    "load_N": ((int, float), None),
}
#: campaign fields that may be lists (expanded as a cartesian product)
_LISTABLE = (
    "muscle_pressure_MPa",
    "waveform",
    "frequency_Hz",
    "amplitude_MPa",
    "offset_MPa",
    "magnitude_MPa",
    "muscle",
    "held_position_mm",
    "load_N",
)


@dataclass(frozen=True)
class RunSpec:
    """One isobaric run.  Pressures MPa gauge, times s, frequency Hz."""

    name: str
    muscle_pressure_MPa: float
    waveform: str
    frequency_Hz: float
    amplitude_MPa: float
    offset_MPa: float
    cycles: float = 3.0
    ramp_s: float = 2.0
    settle_s: float = 1.0
    #: cylinder command held during the settle time, blended into the waveform by the ramp
    preload_MPa: float = 0.0
    role: str = "identification"
    #: square waves: fraction of the period spent on each (raised-cosine) edge
    square_edge: float = 0.05
    pressure_tolerance_MPa: float = 0.01
    pressure_stable_s: float = 0.5
    pressure_timeout_s: float = 120.0
    description: str = ""
    #: where it came from: "run[0]" or "campaign[1] 'pressure'"
    origin: str = ""
    #: a rig with several muscles: the one held isobaric at ``muscle_pressure_MPa`` (the
    #: other muscle's regulator plays the cylinder's role: it stretches and releases it);
    #: "" on a single-muscle rig
    muscle: str = ""
    #: isobaric | isometric | isotonic (see the module docstring)
    test_type: str = "isobaric"
    #: isometric: the contraction held (mm); isotonic: the hanging load (N)
    held_position_mm: float | None = None
    load_N: float | None = None

    @property
    def static(self) -> bool:
        """The muscle's regulator plays the waveform (isometric, isotonic)."""
        return self.test_type != "isobaric"

    @property
    def steady_start_s(self) -> float:
        """Start of the full-amplitude cycles, s after the run's time zero."""
        return self.settle_s + self.ramp_s

    @property
    def steady_end_s(self) -> float:
        return self.steady_start_s + self.cycles / self.frequency_Hz

    @property
    def duration_s(self) -> float:
        """Recorded length: settle + ramp in + cycles + ramp out."""
        return self.steady_end_s + self.ramp_s

    @property
    def max_command_MPa(self) -> float:
        return self.offset_MPa + self.amplitude_MPa

    @property
    def min_command_MPa(self) -> float:
        return self.offset_MPa - self.amplitude_MPa

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    def to_json(self) -> str:
        return json.dumps(self.to_dict(), sort_keys=True)


@dataclass
class Protocol:
    """A validated protocol: its runs in order (campaigns already expanded)."""

    name: str
    runs: list[RunSpec]
    path: str = ""
    description: str = ""
    sample_rate_Hz: float = SAMPLE_RATE_HZ
    #: the TOML text as read (provenance)
    text: str = ""
    extra: dict[str, Any] = field(default_factory=dict)

    @property
    def duration_s(self) -> float:
        return sum(r.duration_s for r in self.runs)

    def select(self, roles: list[str] | None = None, names: list[str] | None = None) -> Protocol:
        """A copy holding only the runs with one of ``roles`` / ``names`` (None: all)."""
        runs = [
            r
            for r in self.runs
            if (roles is None or r.role in roles) and (names is None or r.name in names)
        ]
        if not runs:
            want = ", ".join((roles or []) + (names or []))
            raise ConfigError(f"{self.path or self.name}: no run matches {want!r}")
        return Protocol(
            self.name,
            runs,
            self.path,
            self.description,
            self.sample_rate_Hz,
            self.text,
            dict(self.extra),
        )


# --------------------------------------------------------------------------- loading
def resolve_protocol_path(spec: str | Path) -> Path:
    """A path, or the bare name of a shipped protocol (``seed-bouc-wen``)."""
    p = shipped(spec, PROTOCOLS_DIR)
    if p.exists():
        return p
    raise ConfigError(f"{spec}: no such protocol file{shipped_hint(PROTOCOLS_DIR, 'protocols')}")


def load_protocol(path: str | Path) -> Protocol:
    """Read and validate a protocol TOML file (a path or a shipped protocol's name)."""
    p = resolve_protocol_path(path)
    text = read_text(p, "protocol file")
    return parse_protocol(text, str(p))


def parse_protocol(text: str, where: str = "<protocol>") -> Protocol:
    """Validate protocol TOML text; ``where`` names the file in error messages."""
    doc = parse_toml(text, where)
    check_keys(
        doc,
        {"protocol", "defaults", "run", "campaign"},
        "{where}: unknown section '{key}' (expected one of: {known})",
        where=where,
    )
    head = doc.get("protocol", {})
    if not isinstance(head, dict):
        raise ConfigError(f"{where}: [protocol] must be a table")
    check_keys(
        head,
        ("name", "description", "sample_rate_Hz"),
        "{where}: [protocol]: unknown field '{key}'",
        where=where,
    )
    name = head.get("name", Path(where).stem)
    if not isinstance(name, str) or not name:
        raise ConfigError(f"{where}: [protocol]: field 'name' must be a non-empty string")
    rate = head.get("sample_rate_Hz", SAMPLE_RATE_HZ)
    if (
        not isinstance(rate, int | float)
        or isinstance(rate, bool)
        or not math.isfinite(rate)
        or not 0 < rate <= MAX_SAMPLE_RATE_HZ
    ):
        raise ConfigError(
            f"{where}: [protocol]: field 'sample_rate_Hz' must be a number > 0 and "
            f"≤ {MAX_SAMPLE_RATE_HZ:g} Hz, got {rate!r}"
        )
    defaults = doc.get("defaults", {})
    if not isinstance(defaults, dict):
        raise ConfigError(f"{where}: [defaults] must be a table")
    _check_fields(defaults, f"{where}: [defaults]", allow_lists=False, allow_name=False)

    runs: list[RunSpec] = []
    tables = {sec: doc.get(sec, []) for sec in ("run", "campaign")}
    for sec, ts in tables.items():
        if not isinstance(ts, list):
            raise ConfigError(f"{where}: '{sec}' must be an array of tables ([[{sec}]])")
    for sec, ts in tables.items():
        for i, t in enumerate(ts):
            ctx = f"{where}: {sec}[{i}]"
            if not isinstance(t, dict):
                raise ConfigError(f"{ctx}: must be a table")
            if isinstance(t.get("name"), str):
                ctx += f" '{t['name']}'"
            if sec == "run":
                _check_fields(t, ctx, allow_lists=False, allow_name=True)
                runs.append(_make_run({**defaults, **t}, ctx, f"run[{i}]", float(rate)))
                continue
            t = dict(t)
            pair = _check_pair(t.pop("pair", None), t, ctx)
            _check_fields(t, ctx, allow_lists=True, allow_name=True)
            runs.extend(
                _expand_campaign({**defaults, **t}, ctx, f"campaign[{i}]", float(rate), pair)
            )
    if not runs:
        raise ConfigError(f"{where}: no [[run]] or [[campaign]] defined")
    seen: dict[str, str] = {}
    for r in runs:
        if r.name in seen:
            raise ConfigError(
                f"{where}: {r.origin}: run name '{r.name}' already used by {seen[r.name]}"
            )
        seen[r.name] = r.origin
    return Protocol(
        name=name,
        runs=runs,
        path=where,
        description=str(head.get("description", "")),
        sample_rate_Hz=float(rate),
        text=text,
    )


def _check_fields(t: dict[str, Any], ctx: str, *, allow_lists: bool, allow_name: bool) -> None:
    for k, v in t.items():
        if k == "name" and allow_name:
            if not isinstance(v, str) or not v or "/" in v or v.strip() != v:
                raise ConfigError(f"{ctx}: field 'name' must be a non-empty string without '/'")
            continue
        if k == "pair":
            raise ConfigError(f"{ctx}: field 'pair' is only allowed in a [[campaign]]")
        if k not in _FIELDS:
            raise ConfigError(f"{ctx}: unknown field '{k}' (known: name, {', '.join(_FIELDS)})")
        typ = _FIELDS[k][0]
        vals = v if (allow_lists and k in _LISTABLE and isinstance(v, list)) else [v]
        if isinstance(v, list) and not (allow_lists and k in _LISTABLE):
            raise ConfigError(f"{ctx}: field '{k}' must be a single value, not a list")
        if not vals:
            raise ConfigError(f"{ctx}: field '{k}' is an empty list")
        for x in vals:
            if isinstance(x, bool) or not isinstance(x, typ):
                want = "a string" if typ is str else "a number"
                raise ConfigError(f"{ctx}: field '{k}' must be {want}, got {x!r}")


def _make_run(t: dict[str, Any], ctx: str, origin: str, rate: float) -> RunSpec:
    """Build and validate one run from merged defaults + table (scalars only)."""
    name = t.get("name")
    if not name:
        raise ConfigError(f"{ctx}: missing field 'name'")
    get = {k: t.get(k, d) for k, (_, d) in _FIELDS.items()}
    tt = get["test_type"]
    if tt not in TEST_TYPES:
        raise ConfigError(
            f"{ctx}: field 'test_type' must be one of {', '.join(TEST_TYPES)}, got {tt!r}"
        )
    static = tt != "isobaric"
    need = {"isometric": "held_position_mm", "isotonic": "load_N"}.get(tt)
    for k in ("held_position_mm", "load_N"):
        if k == need and get[k] is None:
            raise ConfigError(f"{ctx}: missing field '{k}' (an {tt} run holds it)")
        if k != need and get[k] is not None:
            raise ConfigError(f"{ctx}: field '{k}' does not apply to an {tt} run")
    if static:
        if get["muscle_pressure_MPa"] is not None:
            raise ConfigError(
                f"{ctx}: field 'muscle_pressure_MPa' does not apply to an {tt} run (the "
                "waveform commands the muscle pressure: offset/amplitude or magnitude)"
            )
        if get["muscle"]:
            raise ConfigError(f"{ctx}: field 'muscle' does not apply to an {tt} run")
        get["muscle_pressure_MPa"] = 1.0  # placeholder, replaced by the command's mean
        if "ramp_s" not in t:
            get["ramp_s"] = 0.0
    elif get["waveform"] == "steps":
        raise ConfigError(
            f"{ctx}: field 'waveform' 'steps' is for isometric and isotonic runs (a "
            "cylinder is not stepped)"
        )
    if need == "load_N" and not 0 < float(get["load_N"]) <= 1e5:
        raise ConfigError(f"{ctx}: field 'load_N' must be > 0 N and ≤ 1e5 N")
    if need == "held_position_mm" and not -1e3 < float(get["held_position_mm"]) < 1e3:
        raise ConfigError(f"{ctx}: field 'held_position_mm' must be within ±1000 mm")
    for req in ("muscle_pressure_MPa", "frequency_Hz"):
        if get[req] is None:
            raise ConfigError(f"{ctx}: missing field '{req}'")
    if get["magnitude_MPa"] is not None:
        for k in ("amplitude_MPa", "offset_MPa"):
            if k in t and t.get(k) is not None:
                raise ConfigError(
                    f"{ctx}: field '{k}' conflicts with 'magnitude_MPa' "
                    "(magnitude M means offset = amplitude = M/2)"
                )
        m = float(get["magnitude_MPa"])
        if m <= 0:
            raise ConfigError(f"{ctx}: field 'magnitude_MPa' must be > 0, got {m}")
        amp = off = m / 2
    else:
        if get["amplitude_MPa"] is None:
            raise ConfigError(f"{ctx}: missing field 'amplitude_MPa' (or 'magnitude_MPa')")
        amp = float(get["amplitude_MPa"])
        off = float(get["offset_MPa"]) if get["offset_MPa"] is not None else amp
    wf = get["waveform"]
    if wf not in WAVEFORMS:
        raise ConfigError(
            f"{ctx}: field 'waveform' must be one of {', '.join(WAVEFORMS)}, got {wf!r}"
        )
    if get["role"] not in ROLES:
        raise ConfigError(
            f"{ctx}: field 'role' must be one of {', '.join(ROLES)}, got {get['role']!r}"
        )
    for k, v in get.items():
        if isinstance(v, float) and not math.isfinite(v):
            raise ConfigError(f"{ctx}: field '{k}' must be a finite number, got {v}")
    f = float(get["frequency_Hz"])
    checks = [
        ("muscle_pressure_MPa", float(get["muscle_pressure_MPa"]) > 0, "must be > 0"),
        (
            "muscle_pressure_MPa",
            float(get["muscle_pressure_MPa"]) <= MAX_GAUGE_MPA,
            f"must be ≤ {MAX_GAUGE_MPA:g} MPa (beyond any PMA rig; a unit mistake?)",
        ),
        (
            "offset_MPa",
            off + amp <= MAX_GAUGE_MPA,
            f"+ amplitude_MPa must be ≤ {MAX_GAUGE_MPA:g} MPa (beyond any regulator)",
        ),
        ("frequency_Hz", f > 0, "must be > 0"),
        (
            "frequency_Hz",
            f <= rate / 20,
            f"must be ≤ {rate / 20:g} Hz (20 samples per period at {rate:g} Hz)",
        ),
        ("amplitude_MPa", amp > 0, "must be > 0"),
        (
            "offset_MPa",
            off - amp >= -1e-12,
            "must be ≥ amplitude_MPa (a regulator cannot command negative pressure)",
        ),
        ("cycles", float(get["cycles"]) > 0, "must be > 0"),
        ("ramp_s", float(get["ramp_s"]) >= 0, "must be ≥ 0"),
        ("settle_s", float(get["settle_s"]) >= 0, "must be ≥ 0"),
        (
            "preload_MPa",
            0 <= float(get["preload_MPa"]) <= off + amp,
            "must be within [0, offset + amplitude]",
        ),
        ("square_edge", 0 <= float(get["square_edge"]) <= 0.25, "must be within [0, 0.25]"),
        ("pressure_tolerance_MPa", float(get["pressure_tolerance_MPa"]) > 0, "must be > 0"),
        ("pressure_stable_s", float(get["pressure_stable_s"]) > 0, "must be > 0"),
        ("pressure_timeout_s", float(get["pressure_timeout_s"]) > 0, "must be > 0"),
    ]
    for fld, ok, msg in checks:
        if not ok:
            val = {"amplitude_MPa": amp, "offset_MPa": off}.get(fld, get.get(fld))
            raise ConfigError(f"{ctx}: field '{fld}' {msg}, got {val}")
    if static:
        # the run starts and settles at the waveform's minimum
        get["preload_MPa"] = off - amp
    return RunSpec(
        name=str(name),
        muscle_pressure_MPa=off if static else float(get["muscle_pressure_MPa"]),
        waveform=wf,
        frequency_Hz=f,
        amplitude_MPa=amp,
        offset_MPa=off,
        cycles=float(get["cycles"]),
        ramp_s=float(get["ramp_s"]),
        settle_s=float(get["settle_s"]),
        preload_MPa=float(get["preload_MPa"]),
        role=str(get["role"]),
        square_edge=float(get["square_edge"]),
        pressure_tolerance_MPa=float(get["pressure_tolerance_MPa"]),
        pressure_stable_s=float(get["pressure_stable_s"]),
        pressure_timeout_s=float(get["pressure_timeout_s"]),
        description=str(get["description"]),
        origin=origin,
        muscle=str(get["muscle"]),
        test_type=tt,
        held_position_mm=None if need != "held_position_mm" else float(get[need]),
        load_N=None if need != "load_N" else float(get[need]),
    )


def _fmt_val(k: str, v: Any) -> str:
    if k == "muscle_pressure_MPa":
        return f"{round(float(v) * 1000):d}kPa"
    if k == "frequency_Hz":
        return f"{float(v):g}Hz"
    if k == "muscle":
        return str(v)
    if k == "held_position_mm":
        return f"{float(v):g}mm"
    if k == "load_N":
        return f"{float(v):g}N"
    if k.endswith("_MPa"):
        return f"{k.split('_')[0][:3]}{round(float(v) * 1000):d}kPa"
    return str(v)


def _check_pair(pair: Any, t: dict[str, Any], ctx: str) -> tuple[str, ...]:
    """Validate a campaign's ``pair`` (fields zipped together); () when absent."""
    if pair is None:
        return ()
    if not isinstance(pair, list) or len(pair) < 2 or not all(isinstance(k, str) for k in pair):
        raise ConfigError(
            f"{ctx}: field 'pair' must be a list of at least two field names, got {pair!r}"
        )
    for k in pair:
        if k not in _LISTABLE:
            raise ConfigError(
                f"{ctx}: field 'pair': '{k}' cannot be a list (pairable: {', '.join(_LISTABLE)})"
            )
    if len(set(pair)) != len(pair):
        raise ConfigError(f"{ctx}: field 'pair' names a field twice: {pair!r}")
    for k in pair:
        if not isinstance(t.get(k), list):
            raise ConfigError(
                f"{ctx}: field 'pair': '{k}' must be given as a list in this campaign"
            )
    lengths = {k: len(t[k]) for k in pair}
    if len(set(lengths.values())) > 1:
        desc = ", ".join(f"{k} has {n}" for k, n in lengths.items())
        raise ConfigError(
            f"{ctx}: field 'pair': paired lists must have equal lengths ({desc} values)"
        )
    return tuple(pair)


_PLACEHOLDER = re.compile(r"\{([^{}]*)\}")


def _run_name(
    base: str, fields: list[str], values: list[Any], merged: dict[str, Any], ctx: str
) -> str:
    """``base-v1-v2...`` over the varying fields, or ``base`` as a ``{field}`` template."""
    if "{" not in base and "}" not in base:
        suffix = "-".join(_fmt_val(k, v) for k, v in zip(fields, values))
        return f"{base}-{suffix}" if suffix else base

    def fill(m: re.Match[str]) -> str:
        k = m.group(1)
        if k not in _LISTABLE:
            raise ConfigError(
                f"{ctx}: field 'name': unknown placeholder '{{{k}}}' (known: "
                f"{', '.join('{' + f + '}' for f in _LISTABLE)})"
            )
        if merged.get(k) is None:
            raise ConfigError(
                f"{ctx}: field 'name': placeholder '{{{k}}}' but the campaign has no '{k}'"
            )
        return _fmt_val(k, merged[k])

    name = _PLACEHOLDER.sub(fill, base)
    if "{" in name or "}" in name:
        raise ConfigError(f"{ctx}: field 'name': unbalanced braces in {base!r}")
    return name


def _expand_campaign(
    t: dict[str, Any], ctx: str, origin: str, rate: float, pair: tuple[str, ...] = ()
) -> list[RunSpec]:
    """Cartesian product over the listed fields (``pair`` zipped into one axis).

    Run names say what varies (see the module docstring).
    """
    base = t.get("name")
    if not base:
        raise ConfigError(f"{ctx}: missing field 'name'")
    varying = [k for k in _LISTABLE if isinstance(t.get(k), list)]
    # axes: each unpaired list alone; the paired lists as one axis of tuples, placed
    # where the first of them sits among the varying fields
    axes: list[tuple[tuple[str, ...], list[tuple[Any, ...]]]] = []
    for k in varying:
        if k in pair:
            if k == next(f for f in varying if f in pair):
                axes.append((pair, list(zip(*(t[f] for f in pair), strict=True))))
        else:
            axes.append(((k,), [(v,) for v in t[k]]))
    n = math.prod(len(vals) for _, vals in axes) if axes else 1
    if n > 500:
        raise ConfigError(f"{ctx}: expands to {n} runs (more than 500)")
    fields = [k for keys, _ in axes for k in keys]
    out = []
    for combo in itertools.product(*(vals for _, vals in axes)):
        values = [v for group in combo for v in group]
        merged = dict(t)
        merged.update(zip(fields, values))
        merged["name"] = _run_name(str(base), fields, values, merged, ctx)
        out.append(_make_run(merged, f"{ctx} run '{merged['name']}'", origin, rate))
    return out
