"""The HDF5 run-file format (``format = "pmalab.run"``, ``format_version = 1``).

This module is the one contract between acquisition and identification (DESIGN.md):

* root attrs ``format``, ``format_version``;
* one group per run, ``/runs/<name>``, attrs ``muscle_pressure_MPa`` (nominal),
  ``waveform``, ``frequency_Hz``, ``sample_rate_Hz``, ``protocol`` (JSON text), more welcome;
* 1-D datasets of equal length with a ``units`` attr: ``time``, ``position``, ``force``,
  ``muscle_pressure`` (required) and ``cylinder_pressure``, ``cylinder_pressure_command``
  (recorded runs; imported data may lack them).

:func:`read_runs` converts every channel to the canonical units (s, mm, N, MPa) and turns
every malformed input into one :class:`~pmalab.errors.RunFileError` line naming the file,
run and channel.
"""

from __future__ import annotations

import json
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from pmalab.errors import RunFileError

FORMAT = "pmalab.run"
FORMAT_VERSION = 1

REQUIRED_CHANNELS = ("time", "position", "force", "muscle_pressure")
OPTIONAL_CHANNELS = ("cylinder_pressure", "cylinder_pressure_command")
CANONICAL_UNITS = {
    "time": "s",
    "position": "mm",
    "force": "N",
    "muscle_pressure": "MPa",
    "cylinder_pressure": "MPa",
    "cylinder_pressure_command": "MPa",
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
}


@dataclass
class Run:
    """One run, in canonical units: time s, position mm (contraction), force N, pressure MPa."""

    name: str
    time: np.ndarray
    position: np.ndarray
    force: np.ndarray
    muscle_pressure: np.ndarray
    cylinder_pressure: np.ndarray | None = None
    cylinder_pressure_command: np.ndarray | None = None
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
        """A copy holding the samples with ``t_start ≤ time − time[0] ≤ t_end`` (s)."""
        rel = self.time - self.time[0]
        keep = (rel >= t_start) & (rel <= t_end)
        chans = {c: (None if getattr(self, c) is None else getattr(self, c)[keep])
                 for c in (*REQUIRED_CHANNELS, *OPTIONAL_CHANNELS)}
        attrs = dict(self.attrs, window_s=[float(t_start), float(t_end)])
        return Run(name=self.name, attrs=attrs, file=self.file, **chans)

    def steady(self) -> Run:
        """The full-amplitude cycles only, when the recording says where they are.

        A recorded run starts with a settle time and a ramp in: there the muscle may still be
        moving to its new pressure's equilibrium or hang slack (zero tension), which is not
        the isobaric cycling the models describe.  The runner stores the window as attrs
        ``steady_start_s``/``steady_end_s`` (s from the run's first sample); imported runs
        without them are returned whole.
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



def validate_channels(
    path: Path | str, run: str, raw: dict[str, tuple[np.ndarray, str | None]]
) -> dict[str, np.ndarray]:
    """Check and convert raw channels ``{name: (values, units)}`` to canonical units."""
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
        if units not in factors:
            raise _fail(
                path, run, ch, f"unknown unit '{units}' (expected one of {', '.join(factors)})"
            )
        arr = arr.astype(np.float64) * factors[units]
        if not np.all(np.isfinite(arr)):
            bad = int(np.flatnonzero(~np.isfinite(arr))[0])
            raise _fail(path, run, ch, f"NaN or infinite value at sample {bad}")
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


def read_runs(path: str | Path, runs: Iterable[str] | None = None) -> list[Run]:
    """Read every run (or the named ``runs``) of a contract file, in canonical units.

    Raises :class:`RunFileError` with one line naming file, run and channel on any problem.
    Runs recorded by :mod:`pmalab.acquisition` also carry ``attrs["status"]``
    ("completed", "aborted: <reason>", or "running" for a file whose writer was killed),
    ``attrs["timing"]`` (lateness statistics) and ``attrs["device_stats"]`` (the devices'
    link/fault counters at the run's end, a dict; {} when the rig reports none); runs
    never started are skipped.
    """
    path = Path(path)
    if not path.exists():
        raise _fail(path, None, None, "no such file")
    if path.is_dir():
        raise _fail(path, None, None, "is a directory, not a run file")
    f = open_h5(path)
    try:
        fmt = decode_attr(f.attrs.get("format"))
        if fmt != FORMAT:
            raise _fail(path, None, None, f"not a pmalab run file (format attr is {fmt!r})")
        ver = decode_attr(f.attrs.get("format_version"))
        if ver != FORMAT_VERSION:
            raise _fail(path, None, None, f"unsupported format_version {ver!r}")
        if "runs" not in f:
            raise _fail(path, None, None, "no '/runs' group")
        names = list(f["runs"].keys())
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
            g = f["runs"][name]
            raw = {}
            for ch in (*REQUIRED_CHANNELS, *OPTIONAL_CHANNELS):
                if ch in g:
                    ds = g[ch]
                    try:
                        values = ds[()]
                    except OSError as exc:
                        raise _fail(path, name, ch, f"unreadable ({_short(exc)})") from None
                    raw[ch] = (values, decode_attr(ds.attrs.get("units")))
            extra = _recording_state(g)
            if extra:
                # written by the acquisition recorder: a run never started (or aborted
                # before its first samples) holds nothing to read; a run cut by a crash
                # is truncated to the samples every channel has
                n = min((len(v) for v, _ in raw.values()), default=0)
                if n < 2 and runs is None:
                    continue
                if extra.get("status") == "running":
                    raw = {c: (v[:n], u) for c, (v, u) in raw.items()}
            chans = validate_channels(path, name, raw)
            attrs = {k: decode_attr(v) for k, v in g.attrs.items()}
            attrs.update(extra)
            for key in ("protocol", "device_stats"):
                if isinstance(attrs.get(key), str):
                    try:
                        attrs[key] = json.loads(attrs[key])
                    except json.JSONDecodeError:
                        pass
            out.append(Run(name=name, attrs=attrs, file=str(path), **chans))
        if not out:
            raise _fail(path, None, None, "no run holds recorded samples (statuses: "
                        + ", ".join(f"{n}={_recording_state(f['runs'][n]).get('status')}"
                                    for n in names) + ")")
        return out
    except (OSError, KeyError) as exc:
        raise _fail(path, None, None, f"damaged file ({_short(exc)})") from None
    finally:
        f.close()


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
    raise _fail(path, None, None, f"not a readable HDF5 file ({_short(first)})") from None


def _recording_state(g: Any) -> dict[str, Any]:
    """``status`` and ``timing`` of a run made by the acquisition recorder (else {})."""
    out: dict[str, Any] = {}
    if "status" in g:
        out["status"] = decode_attr(g["status"][()]).rstrip("\x00 ")
    if "timing" in g:
        try:
            fields = json.loads(decode_attr(g["timing"].attrs.get("fields", "[]")))
            vals = [float(v) for v in g["timing"][()]]
            out["timing"] = {k: v for k, v in zip(fields, vals) if v == v}
        except (ValueError, TypeError):
            pass
    if "device_stats" in g:
        text = decode_attr(g["device_stats"][()]).rstrip("\x00 ")
        try:
            stats = json.loads(text) if text else {}
        except json.JSONDecodeError:
            stats = {"error": "unreadable device_stats"}
        out["device_stats"] = stats if isinstance(stats, dict) else {"value": stats}
    return out


def read_many(paths: Sequence[str | Path]) -> list[Run]:
    """All runs of all files, in order."""
    runs: list[Run] = []
    for p in paths:
        runs.extend(read_runs(p))
    return runs


def _short(exc: BaseException) -> str:
    return str(exc).splitlines()[0][:120] if str(exc) else type(exc).__name__


def read_run_datasets(path: str | Path, run: str) -> dict[str, tuple[np.ndarray, str]]:
    """Every 1-D dataset of run ``run`` that carries a ``units`` attr, subgroups included
    (``"gains/outer_kp"``), as ``{name: (values, units)}`` in the units stored — the
    channels :func:`read_runs` does not know (references, commands, a controller's gains).
    One-line :class:`RunFileError` naming file and run on any problem."""
    path = Path(path)
    f = open_h5(path)
    out: dict[str, tuple[np.ndarray, str]] = {}
    try:
        if "runs" not in f or run not in f["runs"]:
            raise _fail(path, run, None, "no such run")

        def visit(name: str, obj: Any) -> None:
            if getattr(obj, "ndim", None) == 1 and "units" in obj.attrs:
                out[name] = (np.asarray(obj[()], dtype=np.float64),
                             str(decode_attr(obj.attrs["units"])))

        f["runs"][run].visititems(visit)
    except (OSError, KeyError, ValueError, TypeError) as exc:
        raise _fail(path, run, None, f"damaged file ({_short(exc)})") from None
    finally:
        f.close()
    return out


# --------------------------------------------------------------------------- writing
def write_runs(path: str | Path, runs: Sequence[Run], force: bool = False) -> Path:
    """Write complete in-memory runs to a new contract file (canonical units).

    Recording on a rig uses the incremental, crash-proof writer in
    :mod:`pmalab.acquisition`; this is for imports, tests and derived data.
    """
    import h5py

    from pmalab.paths import check_output, output_failure

    path = check_output(path, force)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        f = h5py.File(path, "w")
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
    grp = f.create_group("runs")
    for run in runs:
        g = grp.create_group(run.name)
        for k, v in run.attrs.items():
            if isinstance(v, dict | list):
                v = json.dumps(v)
            if v is None:
                continue
            g.attrs[k] = v
        for ch, values in run.channels().items():
            ds = g.create_dataset(ch, data=np.asarray(values, dtype=np.float64))
            ds.attrs["units"] = CANONICAL_UNITS[ch]
