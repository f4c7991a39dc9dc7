"""``pmalab import``: a CSV from another DAQ → a contract run file (one run).

Columns are mapped by name (``--time-col`` etc., matched exactly, then ignoring case);
units are given per quantity (``--units position=m,force=kN,time=ms,pressure=kPa``) and
converted to the canonical s, mm, N, MPa by :func:`pmalab.runfile.validate_channels` —
the same checks as reading an HDF5 file (missing channel, NaN, time not increasing, unknown
unit), each failure one line naming the file, run and column.  A CSV without a pressure
column needs ``--pressure MPa`` (the nominal muscle pressure, recorded as a constant).

Sign convention is the contract's: position = contraction (positive = shorter), force =
tension.  A DAQ that records elongation can be flipped with ``--negate position``.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from pmalab.errors import RunFileError
from pmalab.runfile import CANONICAL_UNITS, UNIT_FACTORS, Run, validate_channels, write_runs

#: default column name per channel
DEFAULT_COLUMNS = {
    "time": "time",
    "position": "position",
    "force": "force",
    "muscle_pressure": "muscle_pressure",
    "cylinder_pressure": "cylinder_pressure",
    "cylinder_pressure_command": "cylinder_pressure_command",
}
#: ``--units`` keys: a channel name or a quantity shorthand
_UNIT_KEYS = {
    "time": ("time",),
    "position": ("position",),
    "force": ("force",),
    "pressure": ("muscle_pressure", "cylinder_pressure", "cylinder_pressure_command"),
    "muscle_pressure": ("muscle_pressure",),
    "cylinder_pressure": ("cylinder_pressure", "cylinder_pressure_command"),
    "cylinder_pressure_command": ("cylinder_pressure_command",),
}


@dataclass
class CsvImportOptions:
    """Column mapping, units and run metadata of an import."""

    columns: dict[str, str] = field(default_factory=dict)
    units: dict[str, str] = field(default_factory=dict)
    pressure_MPa: float | None = None
    run: str | None = None
    delimiter: str = ","
    negate: tuple[str, ...] = ()
    waveform: str = "unknown"
    frequency_Hz: float | None = None


def parse_units(text: str | None, where: str = "--units") -> dict[str, str]:
    """``"position=m,force=kN"`` → ``{"position": "m", ...}`` per channel; one-line errors."""
    out: dict[str, str] = {}
    if not text:
        return out
    for item in text.split(","):
        item = item.strip()
        if not item:
            continue
        if "=" not in item:
            raise RunFileError(f"{where}: '{item}' is not KEY=UNIT (e.g. position=m)")
        key, unit = (s.strip() for s in item.split("=", 1))
        if key not in _UNIT_KEYS:
            raise RunFileError(f"{where}: unknown quantity '{key}' (expected one of "
                               f"{', '.join(_UNIT_KEYS)})")
        for ch in _UNIT_KEYS[key]:
            if unit not in UNIT_FACTORS[ch]:
                raise RunFileError(f"{where}: unknown unit '{unit}' for {key} (expected one of "
                                   f"{', '.join(UNIT_FACTORS[ch])})")
            out[ch] = unit
    return out


def read_csv_run(path: str | Path, opts: CsvImportOptions) -> Run:
    """Read one run from a CSV file, converted to canonical units."""
    import pandas as pd

    path = Path(path)
    run = opts.run or path.stem
    if not path.exists():
        raise RunFileError(f"{path}: no such file")
    if path.is_dir():
        raise RunFileError(f"{path}: is a directory, not a CSV file")
    if opts.pressure_MPa is not None and not (
        math.isfinite(opts.pressure_MPa) and opts.pressure_MPa > 0
    ):
        raise RunFileError(f"--pressure: must be a muscle pressure > 0 MPa, got {opts.pressure_MPa:g}")
    try:
        df = pd.read_csv(path, sep=opts.delimiter, comment="#", skipinitialspace=True)
    except OSError as exc:
        raise RunFileError(f"{path}: cannot read ({exc.strerror or exc})") from None
    except (pd.errors.ParserError, pd.errors.EmptyDataError, UnicodeDecodeError, ValueError) as exc:
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise RunFileError(f"{path}: not a readable CSV file ({first[:120]})") from None
    cols = [str(c).strip() for c in df.columns]
    df.columns = cols
    lower = {c.lower(): c for c in cols}

    def find(ch: str, explicit: bool) -> str | None:
        name = opts.columns.get(ch, DEFAULT_COLUMNS[ch])
        if name in cols:
            return name
        if name.lower() in lower:
            return lower[name.lower()]
        if explicit:
            raise RunFileError(f"{path}: run '{run}': channel '{ch}': no column '{name}' "
                               f"(columns: {', '.join(cols)})")
        return None

    raw: dict[str, tuple[np.ndarray, str | None]] = {}
    for ch in DEFAULT_COLUMNS:
        required = ch in ("time", "position", "force") or (
            ch == "muscle_pressure" and opts.pressure_MPa is None)
        col = find(ch, explicit=required or ch in opts.columns)
        if col is None:
            continue
        values = pd.to_numeric(df[col], errors="coerce").to_numpy(dtype=np.float64)
        bad = np.flatnonzero(np.isnan(values) & df[col].notna().to_numpy())
        if bad.size:
            i = int(bad[0])
            raise RunFileError(f"{path}: run '{run}': channel '{ch}': column '{col}' row "
                               f"{i + 2} is not a number ({df[col].iloc[i]!r})")
        if ch in opts.negate:
            values = -values
        raw[ch] = (values, opts.units.get(ch, CANONICAL_UNITS[ch]))
    if "muscle_pressure" not in raw:
        n = len(raw["time"][0])
        raw["muscle_pressure"] = (np.full(n, float(opts.pressure_MPa)), "MPa")
    chans = validate_channels(path, run, raw)
    nominal = (float(opts.pressure_MPa) if opts.pressure_MPa is not None
               else float(np.mean(chans["muscle_pressure"])))
    dt = np.diff(chans["time"])
    attrs = {
        "muscle_pressure_MPa": nominal,
        "waveform": opts.waveform,
        "frequency_Hz": opts.frequency_Hz,
        "sample_rate_Hz": float(1.0 / np.median(dt)),
        "protocol": json.dumps({"imported_from": str(path), "columns": opts.columns,
                                "units": opts.units, "negate": list(opts.negate)}),
        "role": "identification",
        "source": "csv import",
        "status": "completed",
    }
    return Run(name=run, attrs=attrs, file=str(path), **chans)


def import_csv(csv: str | Path, out: str | Path, opts: CsvImportOptions, *,
               force: bool = False) -> Run:
    """Import ``csv`` into a new contract file ``out`` (refuses to overwrite without force)."""
    from pmalab.paths import check_output

    check_output(out, force)
    run = read_csv_run(csv, opts)
    write_runs(out, [run], force=force)
    return run
