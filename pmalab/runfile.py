"""The HDF5 run-file format (``format = "pmalab.run"``, ``format_version = 2``; 1 is read).

This module is the one contract between acquisition and identification (docs/reference/run-file.md):

* root attrs ``format``, ``format_version``;
* one group per run, ``/runs/<name>``, attrs ``muscle_pressure_MPa`` (nominal),
  ``waveform``, ``frequency_Hz``, ``sample_rate_Hz``, ``protocol`` (JSON text), more welcome;
* 1-D datasets of equal length with a ``units`` attr: ``time``, ``position``, ``force``,
  ``muscle_pressure`` (required) and ``cylinder_pressure``, ``cylinder_pressure_command``
  (recorded runs; imported data may lack them), ``branch`` (units ``1``: a test stand's
  state code, 1 = pressurising, 2 = venting; imported when the source has one);
* run attr ``test_type`` (:data:`TEST_TYPES`): which quantities the test held —
  ``isobaric`` (pressure held, length cycled: the default of files without the attr),
  ``isometric`` (length held, ``held_position_mm``, pressure ramped), ``isotonic`` (load
  held, ``load_N``, pressure cycled, length measured) or ``free`` (both inputs vary).

:func:`read_runs` converts every channel to the canonical units (s, mm, N, MPa) and turns
every malformed input into one :class:`~pmalab.errors.RunFileError` line naming the file,
run and channel.

Version 2 declares each run's channels as data (:mod:`pmalab.channels`): the run group's
``channels`` attr lists ``{name, kind, unit, muscle}`` and every channel dataset carries
``kind`` and ``muscle`` attrs, so a file may hold several muscles (an antagonistic pair:
``position_flexor``, ``force_extensor``, ``angle``, ...).  Version 1 (no declaration: the
single-muscle channels above) stays readable.  :func:`read_runs` gives one muscle's view
of a run — its channels under the single-muscle names — which is all identification
needs; ``muscle=`` picks the muscle of a multi-muscle file.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import warnings
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from pmalab.channels import BRANCH_CHANNEL, SINGLE_MUSCLE, STANDARD_CHANNELS, Channels
from pmalab.errors import ConfigError, RunFileError, RunFileWarning
from pmalab.health import check_health
from pmalab.writer_process import WRITER_ATTR
from pmalab.writer_process import alive as writer_alive

if TYPE_CHECKING:  # the windowed reader sits above this module
    from pmalab.runwindows import LongRuns

FORMAT = "pmalab.run"
#: the version written: 2 declares the channels (name, kind, unit, muscle) as attributes
FORMAT_VERSION = 2
#: versions read (1: the single-muscle channels, undeclared)
READABLE_VERSIONS = (1, 2)

#: every sample dataset pmalab writes carries HDF5's Fletcher32 checksum per chunk: a bit
#: flipped or a block zeroed on disk fails the read (one line naming file, run and
#: dataset) instead of reading as plausible samples.  Files written without it still read.
CHECKSUM: dict[str, Any] = {"fletcher32": True}
#: samples per chunk of a dataset written whole (a checksum covers one chunk: 4096 float64
#: samples are 32 KiB, 8 s at 500 Hz)
WRITE_CHUNK = 4096

REQUIRED_CHANNELS = ("time", "position", "force", "muscle_pressure")
OPTIONAL_CHANNELS = ("cylinder_pressure", "cylinder_pressure_command", "branch")
#: what a test holds constant: the pressure (isobaric), the length (isometric), the load
#: (isotonic) or nothing (free); a run without the attr is isobaric (format 1's only kind)
TEST_TYPES = ("isobaric", "isometric", "isotonic", "free")
DEFAULT_TEST_TYPE = "isobaric"
CANONICAL_UNITS = {
    "time": "s",
    "position": "mm",
    "force": "N",
    "muscle_pressure": "MPa",
    "cylinder_pressure": "MPa",
    "cylinder_pressure_command": "MPa",
    "branch": "1",
}

#: factor that converts a value in the given unit to the canonical unit of its quantity
_TIME = {"s": 1.0, "ms": 1e-3}
_LENGTH = {"mm": 1.0, "m": 1e3, "um": 1e-3, "µm": 1e-3}
_FORCE = {"N": 1.0, "kN": 1e3}
_PRESSURE = {"MPa": 1.0, "kPa": 1e-3, "bar": 0.1, "Pa": 1e-6}
UNIT_FACTORS: dict[str, dict[str, float]] = {
    "time": _TIME,
    "position": _LENGTH,
    "force": _FORCE,
    "muscle_pressure": _PRESSURE,
    "cylinder_pressure": _PRESSURE,
    "cylinder_pressure_command": _PRESSURE,
    "branch": {"1": 1.0},
}
#: other spellings of a unit (after brackets are stripped and µ/μ folded to "u")
_UNIT_ALIASES = {"sec": "s", "msec": "ms", "micron": "um", "microns": "um"}


def normalize_unit(channel: str, text: str | None) -> str | None:
    """The key of ``UNIT_FACTORS[channel]`` that ``text`` spells, or None.

    Understands how DAQ exports write units: ``mm``, ``[mm]``, ``(mm)``, ``{mm}``,
    ``µm`` (micro sign U+00B5 or Greek mu U+03BC), ``um``, ``micron``, ``sec``, and any
    letter case when it is unambiguous (``kpa`` → kPa, ``KN`` → kN).
    """
    if text is None or channel not in UNIT_FACTORS:
        return None
    factors = UNIT_FACTORS[channel]
    u = str(text).strip()
    while len(u) >= 2 and u[0] + u[-1] in ("[]", "()", "{}", "<>"):
        u = u[1:-1].strip()
    if u in factors:
        return u
    u = u.replace("\u03bc", "u").replace("\u00b5", "u")
    u = _UNIT_ALIASES.get(u, _UNIT_ALIASES.get(u.lower(), u))
    if u in factors:
        return u
    folded = [k for k in factors if k.lower() == u.lower()]
    return folded[0] if len(folded) == 1 else None


@dataclass(frozen=True)
class Plausible:
    """The range (canonical units) a channel of a PMA test can reach, and a typical
    magnitude used to guess which unit a wrongly labelled channel was really in."""

    lo: float
    hi: float
    typical: float
    what: str


#: gauge pressures: a DMSP muscle is rated 0.6 MPa and the regulators 0.9 MPa, so 1.2 MPa
#: is beyond any rig; below -0.05 MPa (50 kPa of vacuum, 5 % of a 1 MPa gauge's span) is
#: not sensor noise or zero offset.  Forces: a DMSP-20 pulls at most ~1.5 kN; positions:
#: a muscle of a few hundred mm contracts by at most a quarter of its length.
_GAUGE = Plausible(-0.05, 1.2, 0.4, "gauge pressure between -0.05 and 1.2 MPa")
PLAUSIBLE: dict[str, Plausible] = {
    "position": Plausible(-500.0, 500.0, 20.0, "|position| ≤ 500 mm"),
    "force": Plausible(-20e3, 20e3, 500.0, "|force| ≤ 20 kN"),
    "muscle_pressure": _GAUGE,
    "cylinder_pressure": _GAUGE,
    "cylinder_pressure_command": _GAUGE,
}


def likely_unit(channel: str, raw: np.ndarray) -> str | None:
    """The unit in which the raw values ``raw`` of ``channel`` look like a PMA test (within
    :data:`PLAUSIBLE` and nearest its typical magnitude, on a log scale), or None."""
    rule = PLAUSIBLE[channel]
    lo, hi = float(np.min(raw)), float(np.max(raw))
    peak = max(abs(lo), abs(hi))
    best, score = None, math.inf
    for unit, k in UNIT_FACTORS[channel].items():
        if not (rule.lo <= lo * k and hi * k <= rule.hi) or peak == 0:
            continue
        s = abs(math.log(peak * k / rule.typical))
        if s < score:
            best, score = unit, s
    return best


@dataclass
class Run:
    """One run, in canonical units.

    Attributes
    ----------
    name
        The run's name (its group ``/runs/<name>``).
    time
        Sample times, s, increasing (not necessarily from 0).
    position
        Contraction x, mm: positive = shorter than the nominal length.
    force
        Tension F, N: positive pulls.
    muscle_pressure
        Measured muscle pressure, MPa gauge.
    cylinder_pressure, cylinder_pressure_command
        The load cylinder's measured and commanded pressure, MPa gauge (recorded runs;
        imports may lack them).
    attrs
        The run's attributes: ``muscle_pressure_MPa`` (nominal), ``waveform``,
        ``frequency_Hz``, ``sample_rate_Hz``, ``role``, ``status``, ...
    """

    name: str
    time: np.ndarray
    position: np.ndarray
    force: np.ndarray
    muscle_pressure: np.ndarray
    cylinder_pressure: np.ndarray | None = None
    cylinder_pressure_command: np.ndarray | None = None
    #: a test stand's state code per sample (1 = pressurising, 2 = venting), when recorded
    branch: np.ndarray | None = None
    attrs: dict[str, Any] = field(default_factory=dict)
    #: the file the run was read from ("" for in-memory runs)
    file: str = ""

    # convenience accessors for the attrs every run carries
    @property
    def nominal_pressure(self) -> float:
        """Nominal muscle pressure (MPa); falls back to the mean measured pressure."""
        v = self.attrs.get("muscle_pressure_MPa")
        return float(v) if v is not None else float(np.mean(self.muscle_pressure))

    @property
    def state(self) -> str:
        """``completed``, ``aborted``, ``interrupted`` (writer killed) or ``not run``
        (see :func:`run_state`)."""
        return run_state(self.attrs.get("status"))

    @property
    def test_type(self) -> str:
        """``isobaric``, ``isometric``, ``isotonic`` or ``free`` (attr ``test_type``; a run
        without it is isobaric)."""
        v = self.attrs.get("test_type")
        return str(v) if v in TEST_TYPES else DEFAULT_TEST_TYPE

    @property
    def frequency(self) -> float | None:
        v = self.attrs.get("frequency_Hz")
        return None if v is None else float(v)

    @property
    def label(self) -> str:
        """``file:run`` (or just the run name for in-memory runs)."""
        return f"{Path(self.file).name}:{self.name}" if self.file else self.name

    def channels(self) -> dict[str, np.ndarray]:
        out = {c: getattr(self, c) for c in REQUIRED_CHANNELS}
        for c in OPTIONAL_CHANNELS:
            if getattr(self, c) is not None:
                out[c] = getattr(self, c)
        return out

    def to_dataframe(self):  # -> pandas.DataFrame (pandas imported lazily)
        """A tidy DataFrame: one row per sample, one column per channel (canonical units)."""
        import pandas as pd

        df = pd.DataFrame(self.channels())
        df.attrs.update(self.attrs)
        df.attrs["run"] = self.name
        df.attrs["file"] = self.file
        return df

    def __len__(self) -> int:
        return int(self.time.shape[0])

    def window(self, t_start: float, t_end: float) -> Run:
        """A time window of the run, as a new run.

        Parameters
        ----------
        t_start, t_end
            The window's bounds in s from the run's first sample (inclusive).

        Returns
        -------
        Run
            A copy holding the samples with ``t_start ≤ time − time[0] ≤ t_end`` (every
            channel cut alike); its attrs record the window as ``window_s``.
        """
        rel = self.time - self.time[0]
        keep = (rel >= t_start) & (rel <= t_end)
        cp, cpc, br = self.cylinder_pressure, self.cylinder_pressure_command, self.branch
        attrs = dict(self.attrs, window_s=[float(t_start), float(t_end)])
        return Run(
            name=self.name,
            attrs=attrs,
            file=self.file,
            time=self.time[keep],
            position=self.position[keep],
            force=self.force[keep],
            muscle_pressure=self.muscle_pressure[keep],
            cylinder_pressure=None if cp is None else cp[keep],
            cylinder_pressure_command=None if cpc is None else cpc[keep],
            branch=None if br is None else br[keep],
        )

    def steady(self) -> Run:
        """The full-amplitude cycles only, when the recording says where they are.

        A recorded run starts with a settle time and a ramp in: there the muscle may still be
        moving to its new pressure's equilibrium or hang slack (zero tension), which is not
        the isobaric cycling the models describe.  The runner stores the window as attrs
        ``steady_start_s``/``steady_end_s`` (s from the run's first sample).

        Returns
        -------
        Run
            The steady window (:meth:`window`); the run itself when the attrs are absent
            (imported runs) or the window would hold fewer than 100 samples.
        """
        t0, t1 = self.attrs.get("steady_start_s"), self.attrs.get("steady_end_s")
        if t0 is None or t1 is None:
            return self
        trimmed = self.window(float(t0), float(t1))
        return trimmed if len(trimmed) >= 100 else self


# --------------------------------------------------------------------------- reading
def _fail(path: Path | str, run: str | None, channel: str | None, msg: str) -> RunFileError:
    where = str(path)
    if run is not None:
        where += f": run '{run}'"
    if channel is not None:
        where += f": channel '{channel}'"
    return RunFileError(f"{where}: {msg}")


def decode_attr(v: Any, *, parse_json: bool = False) -> Any:
    """An HDF5 attribute value as plain Python (bytes → str, numpy → scalar/list).

    ``parse_json``: also turn JSON object/array text (how dicts are stored) into Python.
    """
    if isinstance(v, bytes):
        v = v.decode("utf-8", "replace")
    elif isinstance(v, np.generic):
        v = v.item()
    elif isinstance(v, np.ndarray):
        v = v.tolist()
    if parse_json and isinstance(v, str) and v[:1] in "{[":
        try:
            return json.loads(v)
        except json.JSONDecodeError:
            return v
    return v


def run_state(status: Any) -> str:
    """What a run's recorded ``status`` means for analysis.

    ``completed`` (or no status: imported and derived data), ``aborted`` (``aborted: <reason>``:
    a limit trip, Ctrl-C, SIGTERM or a device fault cut it), ``interrupted`` (``running``:
    its writer was killed mid-run and the file was never closed) or ``not run``
    (``pending``, ``not run: ...``).
    """
    if status is None:
        return "completed"
    text = str(status).strip()
    if text in ("", "completed"):
        return "completed"
    if text.startswith("aborted"):
        return "aborted"
    if text == "running":
        return "interrupted"
    return "not run"


def _hdf5_units_hint(channel: str, declared: str, unit: str | None) -> str:
    if unit is None:
        return f"check its 'units' attribute ('{declared}')"
    return f"looks like {unit}: its 'units' attribute says '{declared}'"


def validate_channels(
    path: Path | str,
    run: str,
    raw: Mapping[str, tuple[np.ndarray, str | None]],
    units_hint: Callable[[str, str, str | None], str] = _hdf5_units_hint,
    *,
    exempt_last: bool = False,
) -> dict[str, np.ndarray]:
    """Check raw channels and convert them to canonical units.

    Besides the format (1-D, numeric, known unit, finite, equal lengths, time increasing),
    refuses values no PMA test can produce (:data:`PLAUSIBLE`), naming the unit they
    probably are in.

    Parameters
    ----------
    path, run
        The file and run the channels come from (named in any error).
    raw
        ``{channel: (values, declared unit)}``; channels the contract does not know are
        ignored.
    units_hint
        ``units_hint(channel, declared_unit, likely_unit_or_None)`` words the advice after
        a refused value (the CSV import names its ``--units`` option).
    exempt_last
        The last sample is not held to :data:`PLAUSIBLE`: an aborted run keeps the reading
        that tripped its limit (a disconnected 4–20 mA gauge reads −0.25 MPa), and that
        evidence must not make the file unreadable.

    Returns
    -------
    dict of str to numpy.ndarray
        Each known channel as float64 in canonical units: time s, position mm (contraction
        positive), force N (tension positive), pressures MPa gauge.

    Raises
    ------
    pmalab.errors.RunFileError
        One line naming file, run and channel: a missing channel or ``units``, an unknown
        unit, unequal lengths, time not increasing, NaNs, implausible values.
    """
    out: dict[str, np.ndarray] = {}
    for ch in REQUIRED_CHANNELS:
        if ch not in raw:
            raise _fail(path, run, ch, "missing channel")
    n = None
    for ch, (values, units) in raw.items():
        if ch not in UNIT_FACTORS:
            continue
        arr = np.asarray(values)
        if arr.ndim != 1:
            raise _fail(path, run, ch, f"expected a 1-D dataset, got shape {arr.shape}")
        if not np.issubdtype(arr.dtype, np.number):
            raise _fail(path, run, ch, f"not numeric (dtype {arr.dtype})")
        if units is None:
            raise _fail(path, run, ch, "missing 'units' attribute")
        factors = UNIT_FACTORS[ch]
        unit = normalize_unit(ch, units)
        if unit is None:
            raise _fail(
                path, run, ch, f"unknown unit '{units}' (expected one of {', '.join(factors)})"
            )
        rawf = arr.astype(np.float64)
        arr = rawf * factors[unit]
        if not np.all(np.isfinite(arr)):
            bad = int(np.flatnonzero(~np.isfinite(arr))[0])
            raise _fail(path, run, ch, f"NaN or infinite value at sample {bad}")
        rule = PLAUSIBLE.get(ch)
        held = arr[:-1] if exempt_last else arr
        if rule is not None and held.size and not (rule.lo <= held.min() and held.max() <= rule.hi):
            i = int(np.argmax(np.maximum(held - rule.hi, rule.lo - held)))
            canon = CANONICAL_UNITS[ch]
            raise _fail(
                path,
                run,
                ch,
                f"reaches {arr[i]:.4g} {canon} at sample {i}, which no "
                f"PMA test produces ({rule.what}) — "
                + units_hint(ch, str(units), likely_unit(ch, rawf[: held.size])),
            )
        if n is None:
            n = arr.shape[0]
        out[ch] = arr
    lengths = {ch: a.shape[0] for ch, a in out.items()}
    if len(set(lengths.values())) > 1:
        desc = ", ".join(f"{c}={m}" for c, m in lengths.items())
        odd = min(lengths, key=lambda c: (list(lengths.values()).count(lengths[c]), c))
        raise _fail(path, run, odd, f"channels have unequal lengths ({desc})")
    t = out["time"]
    if t.shape[0] < 2:
        raise _fail(path, run, "time", f"too few samples ({t.shape[0]})")
    dt = np.diff(t)
    if np.any(dt <= 0):
        bad = int(np.flatnonzero(dt <= 0)[0]) + 1
        raise _fail(path, run, "time", f"time not strictly increasing at sample {bad}")
    return out


#: the advice a skipped or refused incomplete run carries
INCLUDE_HINT = "--include-aborted uses it anyway"


def recover_hint(path: Path | str) -> str:
    """What makes a file whose writer was killed readable by other HDF5 tools."""
    return (
        f"h5dump/HDFView cannot open this file until 'pmalab recover {path}' "
        f"(or 'h5clear -s {path}')"
    )


def read_runs(
    path: str | Path,
    runs: Iterable[str] | None = None,
    *,
    skip_incomplete: bool = False,
    muscle: str | None = None,
    long_runs: LongRuns | None = None,
    health: bool = True,
) -> list[Run]:
    """Read every run (or the named ``runs``) of a contract file, in canonical units.

    Runs recorded by :mod:`pmalab.acquisition` also carry ``attrs["status"]``
    ("completed", "aborted: <reason>", or "running" for a file whose writer was killed —
    or still records it: such a file is read to the samples flushed so far, with one
    warning naming the live writer, :func:`recording_by`),
    ``attrs["timing"]`` (lateness statistics) and ``attrs["device_stats"]`` (the devices'
    link/fault counters at the run's end, a dict; {} when the rig reports none); runs
    never started are skipped.  A run's ``summary`` dataset (JSON written at its end:
    ``pmalab control``'s metrics, vent outcome) is merged into its attrs.

    ``skip_incomplete`` (what analysis wants): runs that were aborted or interrupted
    (:func:`run_state`) are left out with one :class:`~pmalab.errors.RunFileWarning` each
    — a killed 0.8 s settle fragment is not an isobaric test — unless named in ``runs``;
    a file left with no complete run is an error.

    ``muscle``: which muscle's view a multi-muscle file (version 2) gives — each run's
    channels of that muscle under the single-muscle names (``position``, ``force``,
    ``muscle_pressure``; ``attrs["muscle"]`` says which).  Runs that held another muscle
    isobaric (attr ``held_muscle``) are left out, unless named in ``runs``.  A file with
    several muscles and no ``muscle`` is an error naming them; single-muscle files ignore
    ``None`` and accept their one muscle's name.

    ``health``: judge every measured channel before handing it out (stuck values, spikes
    no muscle makes: :func:`pmalab.health.check_health`) — what analysis wants.  ``False``
    reads the codec alone, for tools that inspect synthetic or damaged values as they are.

    ``long_runs``: a run of at least ``long_runs.min_samples`` samples is not read whole;
    it goes, still on disk, to ``long_runs.read`` (:mod:`pmalab.runwindows`), which reads it
    a window at a time and returns the run to use (e.g. identification's decimation).

    Parameters
    ----------
    path
        The run file (HDF5, ``format = "pmalab.run"``, version 1 or 2).
    runs
        Names of the runs to read (default: every run that was started).
    skip_incomplete
        Leave out aborted and interrupted runs (see above).
    muscle
        The muscle whose view a multi-muscle file gives (see above).
    long_runs
        How to read long runs (see above); ``None``: every run whole.
    health
        Judge every measured channel (see above).

    Returns
    -------
    list of Run
        The runs in file order: time s, position mm (contraction positive), force N
        (tension positive), pressures MPa gauge.

    Raises
    ------
    pmalab.errors.RunFileError
        One line naming file, run and channel on any problem.
    """
    import h5py

    path = Path(path)
    if not path.exists():
        raise _fail(path, None, None, "no such file")
    if path.is_dir():
        raise _fail(path, None, None, "is a directory, not a run file")
    f = open_h5(path)
    killed = bool(getattr(f, "swmr_mode", False))  # opened only in SWMR-read mode
    # ... because its writer still records it (then nothing was killed), or was killed
    recording = recording_by(f)
    killed = killed and recording is None
    in_progress: list[str] = []  # runs the live writer is recording: read as flushed so far
    skipped: list[tuple[str, str]] = []
    never: list[str] = []  # runs of a recorder's file that hold no samples (never started)
    losses: list[str] = []  # a killed writer's torn last chunks: the samples cut
    try:
        fmt = decode_attr(f.attrs.get("format"))
        if fmt != FORMAT:
            raise _fail(path, None, None, f"not a pmalab run file (format attr is {fmt!r})")
        ver = decode_attr(f.attrs.get("format_version"))
        if ver not in READABLE_VERSIONS:
            raise _fail(
                path,
                None,
                None,
                f"unsupported format_version {ver!r} (this pmalab reads "
                f"{', '.join(map(str, READABLE_VERSIONS))}: a newer pmalab wrote it?)",
            )
        check_attrs_digest(path, None, f)
        if "runs" not in f:
            raise _fail(path, None, None, "no '/runs' group")
        runs_g = f["runs"]
        if not isinstance(runs_g, h5py.Group):
            raise _fail(path, None, None, "'/runs' is not a group")
        names = list(runs_g.keys())
        if runs is not None:
            wanted = list(runs)
            for r in wanted:
                if r not in names:
                    raise _fail(path, r, None, f"no such run (file has: {', '.join(names)})")
            names = wanted
        if not names:
            raise _fail(path, None, None, "file holds no runs")
        out = []
        for name in names:
            g = runs_g[name]
            if not isinstance(g, h5py.Group):
                raise _fail(path, name, None, "not a group")
            declared = run_channels(path, name, g)
            picked = _pick_muscle(path, name, declared, muscle)
            held = decode_attr(g.attrs.get("held_muscle"))
            if muscle is not None and held and held != picked and runs is None:
                continue  # another muscle's isobaric run: this muscle was the driven one
            view = declared.single_muscle_view(picked)
            raw = {}
            lazy = long_runs is not None and _run_length(g) >= long_runs.min_samples
            # a killed writer's last chunk may be torn; a live one's is rewritten at every
            # flush: the run is being recorded, its flushed samples read so far
            cut = is_running(g)
            if cut and recording is not None:
                in_progress.append(name)
            for ch in (*REQUIRED_CHANNELS, *OPTIONAL_CHANNELS):
                src = view.get(ch, ch)
                if src in g:
                    ds = g[src]
                    if not isinstance(ds, h5py.Dataset):
                        raise _fail(path, name, src, "not a dataset")
                    if lazy:  # read later, a window at a time
                        held = (
                            lazy_samples(path, name, src, ds, losses, writer=recording)
                            if cut
                            else ds
                        )
                        raw[ch] = (held, decode_attr(ds.attrs.get("units")))
                        continue
                    values, lost = read_samples(path, name, src, ds, killed=cut, writer=recording)
                    if lost:
                        losses.append(lost)
                    raw[ch] = (values, decode_attr(ds.attrs.get("units")))
            check_attrs_digest(path, name, g)
            extra = _recording_state(g, path, name)
            if extra:
                # written by the acquisition recorder: a run never started (or aborted
                # before its first samples) holds nothing to read; a run cut by a crash
                # is truncated to the samples every channel has
                n = min((len(v) for v, _ in raw.values()), default=0)
                if n < 2 and runs is None:
                    never.append(name)
                    continue
                if extra.get("status") == "running" and not lazy:
                    raw = {c: (v[:n], u) for c, (v, u) in raw.items()}
            attrs = {k: decode_attr(v) for k, v in g.attrs.items() if k != "channels"}
            attrs.update(extra)
            if len(declared.muscles) > 1:
                attrs["muscle"] = picked
                attrs["channel_names"] = view
            tt = attrs.get("test_type")
            if tt is not None and tt not in TEST_TYPES:
                raise _fail(
                    path, name, None, f"unknown test_type {tt!r} (one of {', '.join(TEST_TYPES)})"
                )
            status = attrs.get("status")
            if skip_incomplete and runs is None and run_state(status) != "completed":
                skipped.append((name, str(status)))
                continue
            for key in ("protocol", "device_stats"):
                if isinstance(attrs.get(key), str):
                    try:
                        attrs[key] = json.loads(attrs[key])
                    except json.JSONDecodeError:
                        pass
            if lazy:
                assert long_runs is not None
                for ch in REQUIRED_CHANNELS:
                    if ch not in raw:
                        raise _fail(path, name, ch, "missing channel")
                n = min(len(v) for v, _ in raw.values())
                if n < 2:
                    raise _fail(path, name, "time", f"too few samples ({n})")
                run = long_runs.take(
                    path, name, raw, n, attrs, exempt_last=run_state(status) != "completed"
                )
                _check_window(path, name, run.attrs, run.time)
                out.append(run)
                continue
            chans = validate_channels(path, name, raw, exempt_last=run_state(status) != "completed")
            if health:
                check_health(str(path), name, chans)
            _check_window(path, name, attrs, chans["time"])
            out.append(Run(name=name, attrs=attrs, file=str(path), **chans))
        if not out and skipped:
            states = "; ".join(f"run '{n}' {_state_words(s, recording)}" for n, s in skipped)
            raise _fail(
                path,
                None,
                None,
                f"no complete run ({states}); {INCLUDE_HINT}"
                + (f"; {recover_hint(path)}" if killed else ""),
            )
        if not out:
            raise _fail(
                path,
                None,
                None,
                "no run holds recorded samples (statuses: "
                + ", ".join(f"{n}={_recording_state(runs_g[n]).get('status')}" for n in names)
                + ")"
                + (f"; {recover_hint(path)}" if killed else ""),
            )
    except (OSError, KeyError, RuntimeError, ValueError, TypeError, UnicodeError) as exc:
        # HDF5 meets damaged metadata (a header, B-tree or heap whose checksum fails) as an
        # exception of whichever kind the call raises: one line, never a traceback
        raise _fail(path, None, None, f"damaged file ({_short(exc)}); {CHECK_HINT}") from None
    finally:
        f.close()
    for words in losses:
        warnings.warn(RunFileWarning(words), stacklevel=2)
    for name, status in skipped:
        warnings.warn(
            RunFileWarning(
                f"{path}: run '{name}' skipped: {_state_words(status, recording)} ({INCLUDE_HINT})"
                + (f"; {recover_hint(path)}" if killed and status == "running" else "")
            ),
            stacklevel=2,
        )
    if recording is not None:  # said once: the file is not finished
        later = f"; {len(never)} run(s) not recorded yet: {', '.join(never)}" if never else ""
        read = {r.name: len(r) for r in out}
        now = [f"run '{n}' ({read[n]} samples flushed so far)" for n in in_progress if n in read]
        warnings.warn(
            RunFileWarning(
                f"{path}: still being recorded by {recording}"
                + (f": read {', '.join(now)}" if now else "")
                + later
            ),
            stacklevel=2,
        )
    if killed and not any(status == "running" for _, status in skipped):
        # killed between runs (waiting for a pressure, or before closing): no cut run
        # carries the hint, yet other tools cannot open the file
        unrecorded = f" ({len(never)} run(s) never recorded: {', '.join(never)})" if never else ""
        warnings.warn(
            RunFileWarning(
                f"{path}: its recording did not close the file (killed, or still running){unrecorded}; "
                f"{recover_hint(path)}"
            ),
            stacklevel=2,
        )
    return out


def run_channels(path: Path | str, run: str, g: Any) -> Channels:
    """A run group's declared channels (version 2), or the single-muscle channels it holds
    (version 1, or a version-2 writer's own datasets without a declaration)."""
    text = g.attrs.get("channels")
    if text is None:
        return Channels(c for c in (*STANDARD_CHANNELS, BRANCH_CHANNEL) if c.name in g)
    try:
        return Channels.from_attr(decode_attr(text), f"{path}: run '{run}'")
    except ConfigError as exc:
        raise RunFileError(str(exc)) from None


def _pick_muscle(path: Path, run: str, declared: Channels, muscle: str | None) -> str:
    """The muscle whose view is read: ``muscle``, or the file's only one."""
    have = list(declared.muscles) or [SINGLE_MUSCLE]
    if muscle is None:
        if len(have) > 1:
            raise _fail(
                path,
                run,
                None,
                f"holds {len(have)} muscles ({', '.join(have)}): choose one (--muscle NAME)",
            )
        return have[0]
    if muscle not in have:
        raise _fail(path, run, None, f"no muscle '{muscle}' (it has: {', '.join(have)})")
    return muscle


def declare_channels(g: Any, channels: Channels) -> None:
    """Write a run group's channel declaration (format version 2): the group's
    ``channels`` attr and each existing dataset's ``kind``/``muscle`` attrs."""
    g.attrs["channels"] = channels.as_attr()
    for c in channels:
        if c.name in g:
            g[c.name].attrs["kind"] = c.kind
            g[c.name].attrs["muscle"] = c.muscle


def muscles_of(path: str | Path) -> tuple[str, ...]:
    """The muscles a run file's first run declares (``("muscle",)`` for a single-muscle
    file); one-line :class:`RunFileError` when it cannot be read."""
    import h5py

    path = Path(path)
    f = open_h5(path)
    try:
        runs_g = f.get("runs")
        if not isinstance(runs_g, h5py.Group) or not len(runs_g):
            return (SINGLE_MUSCLE,)
        name = next(iter(runs_g.keys()))
        return run_channels(path, name, runs_g[name]).muscles or (SINGLE_MUSCLE,)
    finally:
        f.close()


def recording_by(f: Any) -> str | None:
    """The writer still recording the open run file ``f`` in words (``"process 1234 on
    lab-pc"``), or None: the file was closed, or its writer has ended or cannot be told
    alive (:func:`pmalab.writer_process.alive`; a file of a writer that does not name itself
    is read as killed)."""
    if not getattr(f, "swmr_mode", False):
        return None  # a closed file: its writer is done with it
    try:
        return writer_alive(f.attrs.get(WRITER_ATTR))
    except (OSError, RuntimeError, KeyError):
        return None


def is_running(g: Any) -> bool:
    """The run's recorded status is ``running`` (its writer was killed mid-recording, or
    still records it: :func:`recording_by`)."""
    import h5py

    st = g.get("status")
    if not isinstance(st, h5py.Dataset) or st.shape != ():
        return False
    return str(decode_attr(st[()])).rstrip("\x00 ") == "running"


def _run_length(g: Any) -> int:
    """Samples in a run group's ``time`` dataset (0 when it has none), from its shape."""
    ds = g.get("time")
    shape = getattr(ds, "shape", None)
    return int(shape[0]) if shape else 0


def _state_words(status: str, writer: str | None = None) -> str:
    """A recorded status as words: ``running`` is a writer that was killed, or, with the
    live ``writer`` (:func:`recording_by`), a run still being recorded."""
    if run_state(status) == "interrupted":
        if writer is not None:
            return f"still being recorded by {writer}"
        return "interrupted (its recording was killed mid-run)"
    return status


def _check_window(path: Path, run: str, attrs: dict[str, Any], t: np.ndarray) -> None:
    """Refuse a full-amplitude window (``steady_start_s``/``steady_end_s``, s from the
    run's first sample) that is reversed, negative, or (completed runs) beyond the run."""
    t0, t1 = attrs.get("steady_start_s"), attrs.get("steady_end_s")
    if t0 is None and t1 is None:
        return
    for key, v in (("steady_start_s", t0), ("steady_end_s", t1)):
        if v is None:
            other = "steady_end_s" if key == "steady_start_s" else "steady_start_s"
            raise _fail(path, run, None, f"field '{key}' missing (it has '{other}')")
        if not isinstance(v, int | float) or not math.isfinite(v) or v < 0:
            raise _fail(path, run, None, f"field '{key}' = {v!r}: must be a time ≥ 0 s")
    assert t0 is not None and t1 is not None  # the loop above refused a missing one
    if t1 <= t0:
        raise _fail(
            path,
            run,
            None,
            f"field 'steady_end_s' = {t1:g} s is not after "
            f"'steady_start_s' = {t0:g} s (a reversed window)",
        )
    dur = float(t[-1] - t[0])
    # an aborted or interrupted run stops before the window its protocol planned: only a
    # completed run must hold its window
    if t0 >= dur and run_state(attrs.get("status")) == "completed":
        raise _fail(
            path,
            run,
            None,
            f"field 'steady_start_s' = {t0:g} s is beyond the run's end ({dur:.3g} s)",
        )


def open_h5(path: Path):
    """Open read-only; a file whose SWMR writer died (``kill -9``) still carries the
    "open for write" flag, which HDF5 accepts only in SWMR-read mode, so retry that way."""
    import h5py

    try:
        return h5py.File(path, "r")
    except OSError as exc:
        first = exc
    if "already open for write" in str(first) or "consistency flags" in str(first):
        try:
            return h5py.File(path, "r", swmr=True)
        except OSError:
            pass
    raise _fail(
        path, None, None, f"not a readable HDF5 file ({_short(first)})" + _text_hint(path)
    ) from None


def _text_hint(path: Path) -> str:
    """A text file (no NUL byte at its start) given where a run file belongs is most
    likely a CSV export: name the verb that converts it."""
    try:
        with open(path, "rb") as fh:
            head = fh.read(4096)
    except OSError:
        return ""
    if not head or b"\0" in head:
        return ""
    return f"; it is text: a CSV export? convert it with 'pmalab import {path} --out RUN.h5'"


#: what tells a user which parts of a damaged file are intact
CHECK_HINT = "'pmalab check FILE' reports what is intact"
#: the run attr holding the SHA-256 of the run's other attrs (:func:`attrs_digest`)
DIGEST_ATTR = "attrs_sha256"
#: the statuses the recorder writes (``aborted: …``, ``not run: …`` carry a reason)
_STATUSES = ("pending", "running", "completed")
_STATUS_PREFIXES = ("aborted: ", "not run: ")


def damage_words(exc: BaseException) -> str:
    """An HDF5 read error of a dataset as words: a failed Fletcher32 checksum (a flipped
    bit, a zeroed block) says the stored samples are damaged."""
    text = _short(exc)
    if "filter returned failure" in text or "checksum" in text.lower():
        return f"stored samples damaged (checksum failed: {text}); {CHECK_HINT}"
    return f"unreadable ({text}); {CHECK_HINT}"


def fletcher32(data: bytes) -> int:
    """HDF5's Fletcher32 checksum of ``data`` (what its filter stores, little-endian, after
    a chunk's bytes): 16-bit big-endian words summed modulo 65535, and their running sums.

    Parameters
    ----------
    data : bytes
        The chunk's bytes as stored, before the 4 checksum bytes.

    Returns
    -------
    int
        ``(sum2 << 16) | sum1``, each half reduced modulo 65535.
    """
    words = np.frombuffer(data[: len(data) // 2 * 2], dtype=">u2").astype(np.int64)
    if len(data) % 2:
        words = np.append(words, np.int64(data[-1]) << 8)
    s1 = int(words.sum()) % 65535
    s2 = int((words * np.arange(words.size, 0, -1, dtype=np.int64)).sum()) % 65535
    return (s2 << 16) | s1


def _same_fletcher(a: int, b: int) -> bool:
    """Equal Fletcher32 sums (HDF5 reduces ones'-complement style: 0xffff is 0)."""
    return all(((a >> s) & 0xFFFF) % 65535 == ((b >> s) & 0xFFFF) % 65535 for s in (0, 16))


def rewritten_chunk(ds: Any) -> int | None:
    """The first sample of the chunk a recorder's next flush would have rewritten in place
    (the last one, partly filled), or None when no chunk of ``ds`` can be torn by a kill:
    not a 1-D checksummed chunked dataset, empty, or its last chunk full (no flush rewrites
    a full chunk, so a failure there is damage)."""
    if ds.ndim != 1 or ds.chunks is None or not ds.fletcher32:
        return None
    n, step = int(ds.shape[0]), int(ds.chunks[0])
    if n == 0 or n % step == 0:
        return None
    return (n - 1) // step * step


def torn_tail(ds: Any, start: int, n: int) -> np.ndarray | None:
    """The samples ``start..n`` of a killed writer's last chunk whose checksum fails, when
    the chunk is exactly what the last completed flush wrote; else None.

    A recorder appends into a partly filled chunk, so every flush rewrites that chunk in
    place (same address and size: Fletcher32 adds 4 bytes).  HDF5 writes a flush's raw
    data before its metadata, so a kill during the chunk's ``pwrite`` (Linux copies a write
    page by page and stops at a pending SIGKILL) leaves the first pages new, the rest —
    the checksum, stored last — old, while the dataset's extent on disk is still the old
    one.  Then the samples inside the extent are the old flush's bytes, and the old
    checksum must verify them followed by the fill value (zeros) of the chunk's unwritten
    rest.  Anything else (a flipped bit inside the extent) does not verify: None.
    """
    if ds.compression is not None or ds.shuffle or ds.scaleoffset is not None:
        return None
    if ds.fillvalue != 0 or ds.dtype.kind not in "fiu":
        return None
    size = ds.chunks[0] * ds.dtype.itemsize
    try:
        mask, raw = ds.id.read_direct_chunk((start,))
    except (OSError, ValueError, RuntimeError):
        return None
    if mask != 0 or len(raw) != size + 4:
        return None
    k = (n - start) * ds.dtype.itemsize
    stored = int.from_bytes(raw[-4:], "little")
    sums = fletcher32(bytes(raw[:k]) + bytes(size - k))
    if not _same_fletcher(sums, stored):
        return None
    return np.frombuffer(raw[:k], dtype=ds.dtype).copy()


def read_samples(
    path: Path | str, run: str, name: str, ds: Any, *, killed: bool, writer: str | None = None
) -> tuple[np.ndarray, str | None]:
    """A sample dataset's values, and the words of a loss when its last chunk was torn.

    Parameters
    ----------
    path, run, name : str
        The file, run and dataset named by any error.
    ds : h5py.Dataset
        The dataset (read whole).
    killed : bool
        The run's recorded status is ``running``: its writer died mid-recording, so a
        failed checksum of its *last* chunk is the chunk a flush was rewriting when the
        kill came (:func:`torn_tail`).  Its samples are kept when the old checksum
        verifies them; otherwise the run is cut at that chunk's first sample and the
        words of the lost span are returned (a recorded loss, never invented samples).
    writer : str, optional
        The live writer still recording the run (:func:`recording_by`): a failed last
        chunk is one that writer is rewriting at this moment, read the same way, and the
        words say the samples past the cut are not yet readable, not lost.

    Returns
    -------
    (ndarray, str or None)
        The values, and None or the loss's words (a warning's text).

    Raises
    ------
    RunFileError
        Any other failed read (a chunk before the last one, or a run that ended normally):
        stored samples damaged, one line naming file, run and dataset.
    """
    try:
        return np.asarray(ds[()]), None
    except OSError as exc:
        first = exc
    start = rewritten_chunk(ds) if killed else None
    if start is None:
        raise _fail(path, run, name, damage_words(first))
    n = int(ds.shape[0])
    try:
        head = np.asarray(ds[:start])
    except OSError:  # an earlier, long-finished chunk: damage, not a tear
        raise _fail(path, run, name, damage_words(first)) from None
    tail = torn_tail(ds, start, n)
    if tail is not None:
        return np.concatenate([head, tail]), None
    return head, _loss_words(path, run, name, start, n, writer)


def _loss_words(
    path: Path | str, run: str, name: str, start: int, n: int, writer: str | None = None
) -> str:
    if writer is not None:  # a flush in progress: nothing is lost
        return (
            f"{path}: run '{run}': the last chunk of '{name}' (samples {start}..{n - 1}) is "
            f"being rewritten by {writer}, which still records the run: read to its first "
            f"{start} samples; the rest are not lost (read again once the flush is done)"
        )
    return (
        f"{path}: run '{run}': the last chunk of '{name}' (samples {start}..{n - 1}) fails "
        f"its checksum: torn by the kill that stopped the recording; the run is cut to "
        f"its first {start} samples ({n - start} lost)"
    )


class _Spliced:
    """A long run's dataset read a window at a time whose torn last chunk (from sample
    ``start``) is replaced by the samples its previous checksum verified (``tail``; empty
    when none verified: the dataset is cut there)."""

    def __init__(self, ds: Any, start: int, tail: np.ndarray) -> None:
        self.ds, self.start, self.tail = ds, start, tail

    def __len__(self) -> int:
        return self.start + self.tail.size

    def __getitem__(self, key: slice) -> np.ndarray:
        a, b, _ = key.indices(len(self))
        b = max(a, b)
        head = self.ds[a : min(b, self.start)] if a < self.start else self.tail[:0]
        return np.concatenate([head, self.tail[max(a - self.start, 0) : max(b - self.start, 0)]])


def lazy_samples(
    path: Path | str, run: str, name: str, ds: Any, losses: list[str], writer: str | None = None
) -> Any:
    """A killed run's dataset for windowed reads (:mod:`pmalab.runwindows`): ``ds`` itself
    when its last chunk reads, else that chunk's verified samples spliced in, or the
    dataset cut before it with the loss's words appended to ``losses``
    (:func:`read_samples` does the same for a dataset read whole)."""
    start = rewritten_chunk(ds)
    if start is None:
        return ds
    n = int(ds.shape[0])
    try:
        ds[start:n]
        return ds
    except OSError:
        pass
    tail = torn_tail(ds, start, n)
    if tail is None:
        losses.append(_loss_words(path, run, name, start, n, writer))
        tail = np.zeros(0, dtype=ds.dtype)
    return _Spliced(ds, start, tail)


def attrs_digest(obj: Any) -> str:
    """SHA-256 (hex) of the attributes of a run group and of every dataset in it (a file's
    root: its own attributes only), as stored, except :data:`DIGEST_ATTR` itself.

    HDF5 checksums object headers but not the heaps where text attributes and a group's
    many attributes live, so a damaged byte there could change a nominal pressure, a
    frequency or a channel's units silently; writers store this digest once the
    attributes are final and readers compare it."""
    items = [(str(k), repr(decode_attr(v))) for k, v in obj.attrs.items() if k != DIGEST_ATTR]
    if getattr(obj, "name", "/") != "/":

        def visit(name: str, child: Any) -> None:
            items.extend((f"{name}/{k}", repr(decode_attr(v))) for k, v in child.attrs.items())

        obj.visititems(visit)
    return hashlib.sha256(repr(sorted(items)).encode("utf-8")).hexdigest()


#: attributes a run group keeps in its (checksummed) object header before HDF5 would move
#: them to "dense" storage — a heap and a B-tree whose damage can send the library round a
#: loop instead of failing a checksum
COMPACT_ATTRS = 1000


def create_run_group(parent: Any, name: str) -> Any:
    """A new run group in ``parent`` whose attributes stay in its object header
    (:data:`COMPACT_ATTRS`), where HDF5 checksums them."""
    import h5py

    gcpl = h5py.h5p.create(h5py.h5p.GROUP_CREATE)
    gcpl.set_attr_phase_change(COMPACT_ATTRS, COMPACT_ATTRS - 1)
    h5py.h5g.create(parent.id, name.encode("utf-8"), gcpl=gcpl)
    return parent[name]


def seal_attrs(obj: Any) -> None:
    """Make the attributes of ``obj`` (a run group and everything in it, or a file's root)
    tamper-evident once they are final: text stored as fixed-length UTF-8 (inside the
    checksummed object headers, not in HDF5's global heap, which has no checksum and whose
    damage can even hang the library), then :func:`attrs_digest` stored beside them."""
    _fixed_text(obj)
    if getattr(obj, "name", "/") != "/":
        obj.visititems(lambda _name, child: _fixed_text(child))
    obj.attrs[DIGEST_ATTR] = attrs_digest(obj)


def _fixed_text(obj: Any) -> None:
    """Rewrite ``obj``'s variable-length text attributes as fixed-length UTF-8 bytes (read
    back through :func:`decode_attr` as the same text)."""
    for k in list(obj.attrs.keys()):
        v = obj.attrs[k]
        if isinstance(v, str):
            obj.attrs[k] = np.bytes_(v.encode("utf-8"))


def check_attrs_digest(path: Path | str, run: str | None, obj: Any) -> None:
    """Refuse a group whose attributes no longer match their digest (files without a
    digest, written before it existed, are read as they are)."""
    want = obj.attrs.get(DIGEST_ATTR)
    if want is None:
        return
    if decode_attr(want) != attrs_digest(obj):
        raise _fail(
            path,
            run,
            None,
            "attributes changed since written (their checksum does not match: damaged, or "
            f"edited by another tool; after a deliberate edit delete the '{DIGEST_ATTR}' "
            f"attribute); {CHECK_HINT}",
        )


def _recording_state(
    g: Any, path: Path | str | None = None, run: str | None = None
) -> dict[str, Any]:
    """``status`` and ``timing`` of a run made by the acquisition recorder (else {}).

    With ``path`` (the reader): a status the recorder never writes (a damaged byte) is
    refused rather than read as some state."""
    out: dict[str, Any] = {}
    if "status" in g:
        raw_status = g["status"][()]
        out["status"] = decode_attr(raw_status).rstrip("\x00 ")
        st = out["status"]
        if path is not None and not (st in _STATUSES or st.startswith(_STATUS_PREFIXES)):
            raise _fail(
                path, run, "status", f"damaged ({st[:40]!r} is no recorded status); {CHECK_HINT}"
            )
    if "timing" in g:
        try:
            fields = json.loads(decode_attr(g["timing"].attrs.get("fields", "[]")))
            vals = [float(v) for v in g["timing"][()]]
            if path is not None and vals and all(v == 0.0 for v in vals):
                # written NaN, then real statistics (a start time > 0): all zeros is a block
                # of zeros over the chunk and its checksum (Fletcher32 of zeros is zero)
                raise _fail(path, run, "timing", f"damaged (all zeros); {CHECK_HINT}")
            out["timing"] = {k: v for k, v in zip(fields, vals) if v == v}
        except (ValueError, TypeError):
            pass
    if "summary" in g:  # end-of-run facts of a control run (JSON bytes; empty until its end)
        raw = bytes(np.asarray(g["summary"][()], dtype=np.uint8))
        try:
            doc = json.loads(raw.decode("utf-8")) if raw else {}
        except (UnicodeDecodeError, json.JSONDecodeError):
            doc = {}
        if isinstance(doc, dict):
            out.update({k: v for k, v in doc.items() if k not in ("status", "timing")})
    if "device_stats" in g:
        text = decode_attr(g["device_stats"][()]).rstrip("\x00 ")
        try:
            stats = json.loads(text) if text else {}
        except json.JSONDecodeError:
            stats = {"error": "unreadable device_stats"}
        out["device_stats"] = stats if isinstance(stats, dict) else {"value": stats}
    return out


def read_many(
    paths: Sequence[str | Path],
    *,
    include_aborted: bool = False,
    long_runs: LongRuns | None = None,
    muscle: str | None = None,
) -> list[Run]:
    """All complete runs of all files, in order, for analysis.

    Aborted and interrupted runs are skipped with a warning unless ``include_aborted``
    (:func:`read_runs`); a file given twice is refused (:func:`check_distinct`);
    ``long_runs`` and ``muscle`` as :func:`read_runs`.
    """
    check_distinct(paths)
    runs: list[Run] = []
    for p in paths:
        runs.extend(
            read_runs(p, skip_incomplete=not include_aborted, long_runs=long_runs, muscle=muscle)
        )
    check_distinct_runs(runs)
    return runs


def check_distinct_runs(runs: Sequence[Run]) -> None:
    """Refuse the same recording read from two files (a copied file given twice): equal
    run name and identical time and force samples."""
    seen: dict[tuple[str, int, str], Run] = {}
    for r in runs:
        digest = hashlib.sha1(
            np.ascontiguousarray(r.time).tobytes() + np.ascontiguousarray(r.force).tobytes()
        ).hexdigest()
        key = (r.name, len(r), digest)
        first = seen.setdefault(key, r)
        if first is not r and first.file != r.file:
            raise RunFileError(
                f"{r.file}: run '{r.name}': the same recording as "
                f"{first.label} (a copy of one file?): use each recording once"
            )


def check_distinct(
    paths: Sequence[str | Path], other: Sequence[str | Path] = (), other_name: str = "--validate"
) -> None:
    """Refuse a file given twice (in ``paths``, or in both ``paths`` and ``other``).

    Refused rather than de-duplicated: the same runs counted twice weigh double in the
    pressure laws, and one file as both training and held-out data makes validation
    meaningless; the second name is most likely a typo for another file, which a silent
    de-duplication would hide.
    """
    seen: dict[tuple[int, int] | str, tuple[Path, str]] = {}
    for group, items in (("", paths), (other_name, other)):
        for p in items:
            p = Path(p)
            try:
                st = os.stat(p)
                key: tuple[int, int] | str = (st.st_dev, st.st_ino)
            except OSError:
                key = str(p.resolve())  # missing: read_runs names it
            if key in seen:
                first, first_group = seen[key]
                same = "" if str(first) == str(p) else f" (the same file as {first})"
                where = (
                    f"given both as input and to {group}"
                    if group and not first_group
                    else "given twice"
                )
                raise RunFileError(f"{p}: file {where}{same}: use each file once")
            seen[key] = (p, group)


def _short(exc: BaseException) -> str:
    return str(exc).splitlines()[0][:120] if str(exc) else type(exc).__name__


def read_run_datasets(path: str | Path, run: str) -> dict[str, tuple[np.ndarray, str]]:
    """Every 1-D dataset of run ``run`` that carries a ``units`` attr, subgroups included
    (``"gains/outer_kp"``), as ``{name: (values, units)}`` in the units stored — the
    channels :func:`read_runs` does not know (references, commands, a controller's gains).
    A run whose writer was killed (status ``running``) is cut to the samples every dataset
    holds, one its writer still records to the samples flushed so far.  One-line :class:`RunFileError` naming file and run on any problem."""
    import h5py

    path = Path(path)
    f = open_h5(path)
    out: dict[str, tuple[np.ndarray, str]] = {}
    losses: list[str] = []
    try:
        if "runs" not in f:
            raise _fail(path, run, None, "no such run")
        runs_g = f["runs"]
        if not isinstance(runs_g, h5py.Group) or run not in runs_g:
            raise _fail(path, run, None, "no such run")

        def visit(name: str, obj: Any) -> None:
            if getattr(obj, "ndim", None) == 1 and "units" in obj.attrs:
                values, lost = read_samples(path, run, name, obj, killed=cut, writer=writer)
                if lost:
                    losses.append(lost)
                out[name] = (
                    np.asarray(values, dtype=np.float64),
                    str(decode_attr(obj.attrs["units"])),
                )

        g = runs_g[run]
        if not isinstance(g, h5py.Group):
            raise _fail(path, run, None, "not a group")
        cut = is_running(g)
        writer = recording_by(f) if cut else None
        g.visititems(visit)
        if out and _recording_state(g).get("status") == "running":
            # a writer killed mid-append: every channel up to what all of them hold
            n = min(v.shape[0] for v, _ in out.values())
            out = {k: (v[:n], u) for k, (v, u) in out.items()}
    except (OSError, KeyError, ValueError, TypeError) as exc:
        raise _fail(path, run, None, f"damaged file ({_short(exc)})") from None
    finally:
        f.close()
    for words in losses:
        warnings.warn(RunFileWarning(words), stacklevel=2)
    return out


# --------------------------------------------------------------------------- writing
def write_runs(path: str | Path, runs: Sequence[Run], force: bool = False) -> Path:
    """Write complete in-memory runs to a new contract file (canonical units).

    Recording on a rig uses the incremental, crash-proof writer in
    :mod:`pmalab.acquisition`; this is for imports, tests and derived data.

    Parameters
    ----------
    path
        The run file to write (its folder is made when missing).
    runs
        The runs, in canonical units (time s, position mm, force N, pressures MPa); each
        becomes ``/runs/<name>`` with its attrs and every channel with its ``units``.
    force
        Overwrite an existing file.

    Returns
    -------
    Path
        The file written.

    Raises
    ------
    pmalab.errors.OutputError
        The file exists (without ``force``) or cannot be written (full disk, no
        permission); no half-written file is left behind.
    """
    import h5py

    from pmalab.paths import check_output, output_failure

    path = check_output(path, force)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        # object headers version 2 (HDF5 1.10+): checksummed, so damaged metadata is refused
        f = h5py.File(path, "w", libver=("v110", "latest"))
    except OSError as exc:
        if not path.is_dir():
            path.unlink(missing_ok=True)  # an empty file a full disk let h5py create
        raise output_failure(path, exc) from None
    try:
        _write_groups(f, runs)
        f.close()  # flushes: a full disk may only show here
    except BaseException as exc:
        f.close()
        path.unlink(missing_ok=True)  # no half-written file left behind
        if isinstance(exc, OSError | RuntimeError):  # HDF5: RuntimeError when it cannot flush
            raise output_failure(path, exc) from None
        raise
    return path


def _write_groups(f: Any, runs: Sequence[Run]) -> None:
    """The contract's root attrs, one group per run and its channels (canonical units)."""
    f.attrs["format"] = FORMAT
    f.attrs["format_version"] = FORMAT_VERSION
    seal_attrs(f)
    grp = f.create_group("runs")
    for run in runs:
        g = create_run_group(grp, run.name)
        for k, v in run.attrs.items():
            if isinstance(v, dict | list):
                v = json.dumps(v)
            if v is None:
                continue
            g.attrs[k] = v
        for ch, values in run.channels().items():
            data = np.asarray(values, dtype=np.float64)
            ds = g.create_dataset(
                ch, data=data, chunks=(max(1, min(WRITE_CHUNK, data.shape[0])),), **CHECKSUM
            )
            ds.attrs["units"] = CANONICAL_UNITS[ch]
        declare_channels(
            g, Channels(c for c in (*STANDARD_CHANNELS, BRANCH_CHANNEL) if c.name in g)
        )
        seal_attrs(g)
