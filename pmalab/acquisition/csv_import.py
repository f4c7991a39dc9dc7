"""``pmalab import``: a CSV from another DAQ → a contract run file (one run).

Layout of the text (what LabVIEW, DEWESoft and similar exports write):

* ``header_rows`` lines of metadata before the row of column names (``--header-rows N``);
  blank and ``#`` lines after them are skipped too;
* the names row; a name may carry its unit (``Position [mm]``, ``Force (kN)``);
* optionally a units row under it (``--units-row``: ``[s]``, ``mm``, ``µm``, ``(kPa)``...);
* data rows, fields separated by ``delimiter`` (``,``, ``;``, tab given as ``\\t``) with
  ``decimal`` ``.`` or ``,``, text in ``encoding`` (``cp1252`` for a Windows export's µ).

Columns are mapped by name (``--time-col`` etc., matched exactly, then ignoring case, then
without a unit in brackets).  A column's unit is, first to last: ``--units``
(``position=m,force=kN,time=ms,pressure=kPa``), the units row, the unit in its name, the
canonical one.  Values are converted to s, mm, N, MPa by
:func:`pmalab.runfile.validate_channels` — the same checks as reading an HDF5 file (missing
channel, NaN, time not increasing, unknown unit, and values no PMA test can produce, with the
unit they probably are in), each failure one line naming the file, run and column.  A CSV
without a pressure column needs ``--pressure MPa`` (the nominal muscle pressure, recorded as
a constant).

Sign convention is the contract's: position = contraction (positive = shorter), force =
tension.  A DAQ that records elongation can be flipped with ``--negate position``.
"""

from __future__ import annotations

import codecs
import csv
import io
import json
import math
import os
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from pmalab.errors import OutputError, RunFileError
from pmalab.runfile import (
    CANONICAL_UNITS,
    PLAUSIBLE,
    UNIT_FACTORS,
    Run,
    normalize_unit,
    validate_channels,
    write_runs,
)

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
#: ``--delimiter`` spellings of characters a shell makes awkward
_DELIMITER_NAMES = {"\\t": "\t", "tab": "\t", "TAB": "\t", "semicolon": ";", "comma": ",",
                    "space": " ", "pipe": "|"}
#: a unit written after a column name: ``Position [mm]``, ``Force (kN)``, ``p {bar}``
_NAME_UNIT = re.compile(r"^(.*?)\s*([\[\(\{][^\[\]\(\)\{\}]*[\]\)\}])\s*$")


@dataclass
class CsvImportOptions:
    """Column mapping, units, text layout and run metadata of an import."""

    columns: dict[str, str] = field(default_factory=dict)
    units: dict[str, str] = field(default_factory=dict)
    pressure_MPa: float | None = None
    run: str | None = None
    delimiter: str = ","
    negate: tuple[str, ...] = ()
    waveform: str = "unknown"
    frequency_Hz: float | None = None
    #: lines before the names row (a metadata block)
    header_rows: int = 0
    #: the row under the names holds each column's unit
    units_row: bool = False
    #: decimal mark of the numbers, "." or ","
    decimal: str = "."
    encoding: str = "utf-8"

    def check(self) -> None:
        """Refuse inconsistent layout options (one line naming the option)."""
        if len(self.delimiter) != 1:
            raise RunFileError(f"--delimiter: {self.delimiter!r} is not one character "
                               "(give ',', ';', '\\t' or another single character)")
        if self.decimal not in (".", ","):
            raise RunFileError(f"--decimal: must be '.' or ',', got {self.decimal!r}")
        if self.decimal == self.delimiter:
            raise RunFileError(f"--decimal {self.decimal}: the same character as the "
                               "delimiter (a decimal-comma export separates fields with ';')")
        if self.header_rows < 0:
            raise RunFileError(f"--header-rows: must be ≥ 0, got {self.header_rows}")
        try:
            codecs.lookup(self.encoding)
        except LookupError:
            raise RunFileError(f"--encoding: unknown encoding '{self.encoding}' "
                               "(e.g. utf-8, cp1252, latin-1)") from None


def parse_delimiter(text: str) -> str:
    """``--delimiter`` as typed → the character: ``\\t``/``tab`` → tab, else itself."""
    return _DELIMITER_NAMES.get(text, text)


def parse_units(text: str | None, where: str = "--units") -> dict[str, str]:
    """``"position=m,force=kN"`` → ``{"position": "m", ...}`` per channel; one-line errors.

    Units may be written as in an export's header (``[mm]``, ``µm``, ``um``, ``(kPa)``).
    """
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
            canon = normalize_unit(ch, unit)
            if canon is None:
                raise RunFileError(f"{where}: unknown unit '{unit}' for {key} (expected one of "
                                   f"{', '.join(UNIT_FACTORS[ch])})")
            out[ch] = canon
    return out


def _csv_units_hint(channel: str, declared: str, unit: str | None) -> str:
    key = channel if channel in _UNIT_KEYS else "pressure"
    if unit is None:
        return f"check its unit ('{declared}'; --units {key}=UNIT)"
    return f"looks like {unit}: use --units {key}={unit}"


def _split(line: str, delimiter: str) -> list[str]:
    """One row's fields (quotes honoured), stripped."""
    return [c.strip() for c in next(csv.reader([line], delimiter=delimiter))]


def _read_text(path: Path, opts: CsvImportOptions) -> str:
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise RunFileError(f"{path}: cannot read ({exc.strerror or exc})") from None
    if b"\x00" in data[:4096] and not opts.encoding.lower().startswith("utf-16"):
        raise RunFileError(f"{path}: not a readable CSV file (binary data)")
    try:
        text = data.decode(opts.encoding)
    except UnicodeDecodeError as exc:
        line = data[: exc.start].count(b"\n") + 1
        hint = ("give --encoding (cp1252 for most Windows exports)"
                if opts.encoding.lower().replace("-", "") in ("utf8", "utf8sig")
                else "check --encoding")
        raise RunFileError(f"{path}: line {line}: not {opts.encoding} text (byte "
                           f"0x{data[exc.start]:02x}); {hint}") from None
    return text.lstrip("\ufeff")


def read_csv_run(path: str | Path, opts: CsvImportOptions) -> Run:
    """Read one run from a CSV file, converted to canonical units."""
    import pandas as pd

    path = Path(path)
    run = opts.run or path.stem
    if not path.exists():
        raise RunFileError(f"{path}: no such file")
    if path.is_dir():
        raise RunFileError(f"{path}: is a directory, not a CSV file")
    opts.check()
    if opts.pressure_MPa is not None and not (
        math.isfinite(opts.pressure_MPa) and 0 < opts.pressure_MPa <= PLAUSIBLE[
            "muscle_pressure"].hi
    ):
        raise RunFileError(f"--pressure: must be a muscle pressure > 0 and ≤ "
                           f"{PLAUSIBLE['muscle_pressure'].hi:g} MPa, got {opts.pressure_MPa:g}")
    lines = _read_text(path, opts).splitlines()
    d = opts.delimiter

    # ---- the names row (after the metadata block) and the units row
    i = opts.header_rows
    if i >= len(lines):
        raise RunFileError(f"{path}: --header-rows {opts.header_rows}: the file has only "
                           f"{len(lines)} line(s)")
    while i < len(lines) and (not lines[i].strip() or lines[i].lstrip().startswith("#")):
        i += 1
    if i >= len(lines):
        raise RunFileError(f"{path}: not a readable CSV file (no row of column names)")
    names_line = i + 1  # 1-based, for messages
    names = _split(lines[i], d)
    name_units: list[str | None] = []
    base_names: list[str] = []
    for n in names:
        m = _NAME_UNIT.match(n)
        base_names.append(m.group(1) if m and m.group(1) else n)
        name_units.append(m.group(2) if m and m.group(1) else None)
    i += 1
    row_units: list[str] | None = None
    if opts.units_row:
        if i >= len(lines):
            raise RunFileError(f"{path}: --units-row: no row under the names row "
                               f"(line {names_line})")
        row_units = _split(lines[i], d)
        i += 1
    data_rows = [(k + 1, ln) for k, ln in enumerate(lines[i:], start=i)
                 if ln.strip() and not ln.lstrip().startswith("#")]
    if not data_rows:
        raise RunFileError(f"{path}: not a readable CSV file (no data rows after line "
                           f"{i})")
    def find(ch: str, explicit: bool) -> int | None:
        name = opts.columns.get(ch, DEFAULT_COLUMNS[ch])
        for pool in (names, base_names):
            if name in pool:
                return pool.index(name)
            low = [c.lower() for c in pool]
            if name.lower() in low:
                return low.index(name.lower())
        if explicit:
            needed = [opts.columns.get(c, DEFAULT_COLUMNS[c]) for c in DEFAULT_COLUMNS
                      if c in opts.columns or c in ("time", "position", "force")]
            raise RunFileError(f"{path}: run '{run}': channel '{ch}': no column '{name}' "
                               f"(columns: {', '.join(n for n in names if n)}"
                               + (f" on line {names_line})" if names_line != 1 else ")")
                               + (_header_hint(lines, needed, names_line, d)
                                  or _delimiter_hint(names, d)))
        return None

    wanted: dict[str, int] = {}
    for ch in DEFAULT_COLUMNS:
        required = ch in ("time", "position", "force") or (
            ch == "muscle_pressure" and opts.pressure_MPa is None)
        col = find(ch, explicit=required or ch in opts.columns)
        if col is not None:
            wanted[ch] = col
    # ---- the numbers: pandas' C parser makes every clean column float at once; a column
    # with a bad cell stays text and is converted cell by cell below to name the cell
    try:
        df = pd.read_csv(io.StringIO("\n".join(ln for _, ln in data_rows)), sep=d, header=None,
                         decimal=opts.decimal, keep_default_na=False, na_values=[],
                         skipinitialspace=True)
    except (pd.errors.ParserError, pd.errors.EmptyDataError, ValueError) as exc:
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        m = re.search(r"Expected (\d+) fields in line (\d+), saw (\d+)", first)
        if m and int(m.group(2)) <= len(data_rows):
            raise RunFileError(
                f"{path}: line {data_rows[int(m.group(2)) - 1][0]}: {m.group(3)} fields where the "
                f"rows before have {m.group(1)}; wrong --delimiter or --header-rows?") from None
        raise RunFileError(f"{path}: not a readable CSV file ({first[:120]})") from None
    extra = df.shape[1] - len(names)
    if extra > 0:
        tail = df.iloc[:, len(names):]
        if not tail.astype(str).isin(["", "nan"]).all().all():  # a trailing delimiter is harmless
            raise RunFileError(f"{path}: line {data_rows[0][0]}: {df.shape[1]} fields but "
                               f"{len(names)} column names (line {names_line}); wrong "
                               "--delimiter or --header-rows?")
        df = df.iloc[:, : len(names)]

    raw: dict[str, tuple[np.ndarray, str | None]] = {}
    for ch, col in wanted.items():
        cname = names[col]
        if col >= df.shape[1]:
            raise RunFileError(f"{path}: run '{run}': channel '{ch}': column '{cname}' has no "
                               f"values (rows have {df.shape[1]} fields)")
        column = df.iloc[:, col]
        if np.issubdtype(column.dtype, np.number):
            values = column.to_numpy(dtype=np.float64)
        else:
            text = column.fillna("").astype(str).str.strip()
            num = text.str.replace(",", ".", regex=False) if opts.decimal == "," else text
            values = pd.to_numeric(num, errors="coerce").to_numpy(dtype=np.float64)
            bad = np.flatnonzero(np.isnan(values) & (num.str.lower() != "nan").to_numpy())
            if bad.size:
                k = int(bad[0])
                cell = text.iloc[k]
                raise RunFileError(f"{path}: run '{run}': channel '{ch}': column '{cname}' row "
                                   f"{data_rows[k][0]} is not a number ({cell!r})"
                                   + _cell_hint(cell, k, opts, ch))
        if ch in opts.negate:
            values = -values
        unit = opts.units.get(ch)
        if unit is None and row_units is not None:
            unit = row_units[col] if col < len(row_units) and row_units[col] else None
        if unit is None:
            unit = name_units[col]
        raw[ch] = (values, unit if unit is not None else CANONICAL_UNITS[ch])
    if "muscle_pressure" not in raw:
        n = len(raw["time"][0])
        raw["muscle_pressure"] = (np.full(n, float(opts.pressure_MPa)), "MPa")
    chans = validate_channels(path, run, raw, units_hint=_csv_units_hint)
    nominal = (float(opts.pressure_MPa) if opts.pressure_MPa is not None
               else float(np.mean(chans["muscle_pressure"])))
    dt = np.diff(chans["time"])
    attrs = {
        "muscle_pressure_MPa": nominal,
        "waveform": opts.waveform,
        "frequency_Hz": opts.frequency_Hz,
        "sample_rate_Hz": float(1.0 / np.median(dt)),
        "protocol": json.dumps({"imported_from": str(path), "columns": opts.columns,
                                "units": {c: u for c, (_, u) in raw.items()},
                                "negate": list(opts.negate), "header_rows": opts.header_rows,
                                "delimiter": opts.delimiter, "decimal": opts.decimal,
                                "encoding": opts.encoding}),
        "role": "identification",
        "source": "csv import",
        "status": "completed",
    }
    return Run(name=run, attrs=attrs, file=str(path), **chans)


def _header_hint(lines: list[str], needed: list[str], names_line: int, delimiter: str) -> str:
    """Where the names row probably is: the first other line holding every needed name."""
    want = {n.lower() for n in needed}
    for k, ln in enumerate(lines[:200]):
        if k + 1 == names_line:
            continue
        try:
            fields = _split(ln, delimiter)
        except (csv.Error, StopIteration):
            continue
        have = {f.lower() for f in fields}
        have |= {m.group(1).lower() for f in fields if (m := _NAME_UNIT.match(f)) and m.group(1)}
        if want <= have:
            return f"; the names look like line {k + 1}: use --header-rows {k}"
    return ""


def _delimiter_hint(names: list[str], delimiter: str) -> str:
    """The names row read as one field that another separator would split: say which."""
    if len(names) != 1:
        return ""
    for sep, typed in (("\t", "'\\t'"), (";", "';'"), (",", "','")):
        if sep != delimiter and sep in names[0]:
            return f"; the names are separated by {typed}: use --delimiter {typed}"
    return ""


def _cell_hint(cell: str, k: int, opts: CsvImportOptions, ch: str) -> str:
    """Why a cell did not parse, when it is a known export habit."""
    if k == 0 and not opts.units_row and normalize_unit(ch, cell) is not None:
        return ": a units row? use --units-row"
    if opts.decimal == "." and re.fullmatch(r"[+-]?\d*,\d+([eE][+-]?\d+)?", cell):
        return ": a decimal comma? use --decimal , (with --delimiter ';')"
    return ""


def import_csv(csv: str | Path, out: str | Path, opts: CsvImportOptions, *,
               force: bool = False) -> Run:
    """Import ``csv`` into a new contract file ``out`` (refuses to overwrite without force)."""
    from pmalab.paths import check_output

    if Path(out).exists() and Path(csv).exists() and os.path.samefile(out, csv):
        raise OutputError(f"--out {out}: is the input CSV itself (--force would replace your "
                          "data with the run file): give the run file another name")
    check_output(out, force)
    run = read_csv_run(csv, opts)
    write_runs(out, [run], force=force)
    return run
