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

A file without a names row (LabVIEW's "write to spreadsheet file": tab-separated, CRLF,
numbers from the first line) is read with ``--no-header --columns time,-,-,-,position,pressure,force``:
one name per field, ``-`` for a field to skip.  ``--columns`` names the fields by position
with or without ``--no-header`` (with a names row, the row is skipped and these names used).

A whole campaign is one command (:func:`import_files`): one run per file, the nominal pressure
from the pressure column, ``--pressure MPa`` or the file name (``--pressure-from-name
'(\\d+)bar'``); ``--split-halves`` makes each record two runs, the first half for
identification and the second held out for validation; ``--frequency auto`` reads the
excitation frequency off the position's spectrum.

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
from typing import cast

import numpy as np

from pmalab.acquisition.import_checks import check_import
from pmalab.errors import OutputError, RunFileError, printable
from pmalab.health import check_health
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
    "branch": "branch",
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
_DELIMITER_NAMES = {
    "\\t": "\t",
    "tab": "\t",
    "TAB": "\t",
    "semicolon": ";",
    "comma": ",",
    "space": " ",
    "pipe": "|",
}
#: ``--columns`` names: a channel, or a short name for one; ``-`` skips a field
LAYOUT_NAMES = {
    "t": "time",
    "time": "time",
    "x": "position",
    "position": "position",
    "f": "force",
    "force": "force",
    "p": "muscle_pressure",
    "pressure": "muscle_pressure",
    "muscle_pressure": "muscle_pressure",
    "cylinder_pressure": "cylinder_pressure",
    "cylinder_pressure_command": "cylinder_pressure_command",
    "state": "branch",
    "branch": "branch",
}
#: a unit written after a column name: ``Position [mm]``, ``Force (kN)``, ``p {bar}``
_NAME_UNIT = re.compile(r"^(.*?)\s*([\[\(\{][^\[\]\(\)\{\}]*[\]\)\}])\s*$")


@dataclass
class CsvImportOptions:
    """Column mapping, units, text layout and run metadata of an import.

    Attributes
    ----------
    columns
        Channel → column name in the file (``--time-col`` ...), for files with a names row.
    units
        Channel → unit of the file's values (``--units time=ms,pressure=bar``): time
        s|ms, position mm|m|um, force N|kN, pressure MPa|kPa|bar|Pa.
    pressure_MPa
        The nominal muscle pressure, MPa gauge, of a file without a pressure column
        (``--pressure``).
    position_mm
        The contraction, mm, a file without a position column was held at (isometric).
    load_N
        The constant load, N, of an isotonic test (recorded as an attr).
    test_type
        ``isobaric``, ``isometric``, ``isotonic`` or ``free``; ``None``: recognised from
        the channels.
    run
        The run's name (default: the file's stem).
    delimiter, decimal, encoding
        The text layout: one-character field delimiter, decimal mark ``.`` or ``,``,
        text encoding.
    negate
        Channels whose sign is flipped: pmalab's position is the contraction (positive =
        shorter) and its force the tension (positive pulls); a laser measuring extension
        needs ``("position",)``.
    waveform, frequency_Hz
        The excitation's waveform and frequency, Hz (recorded as attrs).
    header_rows, units_row, no_header, layout
        Lines before the names row, a units row under it, no names row at all, and then
        one channel (or ``None`` for a skipped field) per field (``--columns``).
    drop_duplicate_times
        Drop a sample whose time stamp equals the one before (counted), instead of
        refusing the file.
    """

    columns: dict[str, str] = field(default_factory=dict)
    units: dict[str, str] = field(default_factory=dict)
    pressure_MPa: float | None = None
    #: the contraction (mm) a file without a position channel was held at (isometric)
    position_mm: float | None = None
    #: the constant load (N) of an isotonic test, recorded as an attr
    load_N: float | None = None
    #: the test type to record; None: recognised from the channels (:func:`detect_test_type`)
    test_type: str | None = None
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
    #: the data start on the first line (after ``header_rows``): no names row
    no_header: bool = False
    #: one channel (or ``None`` for a skipped field) per field, from ``--columns``
    layout: list[str | None] | None = None
    #: drop a sample whose time stamp equals the one before (``--drop-duplicate-times``)
    drop_duplicate_times: bool = False

    def check(self) -> None:
        """Refuse inconsistent layout options (one line naming the option)."""
        if len(self.delimiter) != 1:
            raise RunFileError(
                f"--delimiter: {self.delimiter!r} is not one character "
                "(give ',', ';', '\\t' or another single character)"
            )
        if self.decimal not in (".", ","):
            raise RunFileError(f"--decimal: must be '.' or ',', got {self.decimal!r}")
        if self.decimal == self.delimiter:
            raise RunFileError(
                f"--decimal {self.decimal}: the same character as the "
                "delimiter (a decimal-comma export separates fields with ';')"
            )
        if self.header_rows < 0:
            raise RunFileError(f"--header-rows: must be ≥ 0, got {self.header_rows}")
        try:
            codecs.lookup(self.encoding)
        except LookupError:
            raise RunFileError(
                f"--encoding: unknown encoding '{self.encoding}' (e.g. utf-8, cp1252, latin-1)"
            ) from None
        if self.no_header and not self.layout:
            raise RunFileError(
                "--no-header: give the fields' meaning with --columns, e.g. "
                "--columns time,-,position,pressure,force ('-' skips a field)"
            )
        if self.layout is not None and self.columns:
            raise RunFileError(
                "--columns: names the fields by position; do not combine it "
                "with --time-col/--position-col/--force-col/--pressure-col"
            )


def parse_layout(text: str | None, held_position: bool = False) -> list[str | None] | None:
    """``--columns time,-,-,position,pressure,force`` → one channel (or None) per field.

    Short names ``t x f p`` stand for time, position, force and muscle pressure, ``state``
    for a test stand's state code (kept as the ``branch`` channel); each channel appears
    once and time, position and force must all be there — position not when the record
    held its length (``held_position``: ``--position`` or ``--position-from-name``).
    """
    if text is None:
        return None
    out: list[str | None] = []
    for item in (s.strip() for s in text.split(",")):
        if item in ("-", "_", ""):
            out.append(None)
            continue
        ch = LAYOUT_NAMES.get(item.lower())
        if ch is None:
            raise RunFileError(
                f"--columns: unknown field '{item}' (use - to skip a field, "
                f"or one of {', '.join(sorted(LAYOUT_NAMES))})"
            )
        if ch in out:
            raise RunFileError(f"--columns: '{item}' names {ch} twice")
        out.append(ch)
    needed = ("time", "force") if held_position else ("time", "position", "force")
    missing = [c for c in needed if c not in out]
    if missing:
        hint = (
            "; an isometric record held its length: give --position MM or --position-from-name"
            if missing == ["position"]
            else ""
        )
        raise RunFileError(
            f"--columns: no field for {', '.join(missing)} (got {text!r}; '-' skips a field)" + hint
        )
    return out


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
            raise RunFileError(
                f"{where}: unknown quantity '{key}' (expected one of {', '.join(_UNIT_KEYS)})"
            )
        for ch in _UNIT_KEYS[key]:
            canon = normalize_unit(ch, unit)
            if canon is None:
                raise RunFileError(
                    f"{where}: unknown unit '{unit}' for {key} (expected one of "
                    f"{', '.join(UNIT_FACTORS[ch])})"
                )
            out[ch] = canon
    return out


def _csv_units_hint(channel: str, declared: str, unit: str | None) -> str:
    key = channel if channel in _UNIT_KEYS else "pressure"
    if unit is None:
        return f"check its unit ('{declared}'; --units {key}=UNIT)"
    return f"looks like {unit}: use --units {key}={unit}"


def _split(line: str, delimiter: str) -> list[str]:
    """One row's fields (quotes honoured), stripped; a space delimiter takes any run of
    blanks as one separator (column-aligned text)."""
    if delimiter == " ":
        return line.split()
    return [c.strip() for c in next(csv.reader([line], delimiter=delimiter))]


def _is_number(text: str) -> bool:
    try:
        float(text.replace(",", "."))
    except ValueError:
        return False
    return True


def _check_last_row(path: Path, rows: list[tuple[int, str]], delimiter: str) -> None:
    """Refuse a last row cut off mid-number: a file without a final line end whose last row
    has fewer fields, or a field shorter than that field in every one of the rows before it
    (``0.4012`` cut to ``0``, read as 0 MPa)."""
    if len(rows) < 3:
        return
    last = _split(rows[-1][1], delimiter)
    before = [_split(ln, delimiter) for _, ln in rows[-21:-1]]
    width = max(len(f) for f in before)
    if len(last) < width:
        raise RunFileError(
            f"{path}: line {rows[-1][0]}: the last row has {len(last)} of {width} fields and no "
            "line end: the file was cut off (delete that line to import the rest)"
        )
    for k, cell in enumerate(last):
        prev = [len(f[k]) for f in before if k < len(f)]
        if prev and len(cell.strip()) < min(prev):
            raise RunFileError(
                f"{path}: line {rows[-1][0]}: the last row's field {k + 1} is {cell.strip()!r} "
                f"where every row before has {min(prev)}+ characters, and the file has no line "
                "end: it was cut off mid-number (delete that line to import the rest)"
            )


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
        hint = (
            "give --encoding (cp1252 for most Windows exports)"
            if opts.encoding.lower().replace("-", "") in ("utf8", "utf8sig")
            else "check --encoding"
        )
        raise RunFileError(
            f"{path}: line {line}: not {opts.encoding} text (byte 0x{data[exc.start]:02x}); {hint}"
        ) from None
    return text.lstrip("\ufeff")


def read_csv_run(path: str | Path, opts: CsvImportOptions) -> Run:
    """Read one run from a CSV (or other delimited text) export.

    Parameters
    ----------
    path
        The export.
    opts
        Columns, units, delimiter, decimal mark, header rows (:class:`CsvImportOptions`);
        ``opts.run`` names the run (default: the file's stem).

    Returns
    -------
    Run
        The run in canonical units: time s, position mm (contraction positive: give
        ``--negate position`` for a sensor measuring extension), force N (tension
        positive), pressure MPa gauge.

    Raises
    ------
    pmalab.errors.RunFileError
        One line naming the file and the row, column or channel: an unknown unit, a value
        no PMA test can produce (with the unit it probably is in), a short or damaged file.
    """
    import pandas as pd

    path = Path(path)
    run = opts.run or path.stem
    if not path.exists():
        raise RunFileError(f"{path}: no such file")
    if path.is_dir():
        raise RunFileError(f"{path}: is a directory, not a CSV file")
    opts.check()
    if opts.pressure_MPa is not None and not (
        math.isfinite(opts.pressure_MPa)
        and 0 < opts.pressure_MPa <= PLAUSIBLE["muscle_pressure"].hi
    ):
        raise RunFileError(
            f"--pressure: must be a muscle pressure > 0 and ≤ "
            f"{PLAUSIBLE['muscle_pressure'].hi:g} MPa, got {opts.pressure_MPa:g}"
        )
    text = _read_text(path, opts)
    if "\x00" in text:
        raise RunFileError(
            f"{path}: binary zeros at character {text.index(chr(0))}: a damaged text file "
            "(a lost disk block?), not an export"
        )
    lines = text.splitlines()
    d = opts.delimiter

    # ---- the names row (after the metadata block) and the units row
    i = opts.header_rows
    if i >= len(lines):
        raise RunFileError(
            f"{path}: --header-rows {opts.header_rows}: the file has only {len(lines)} line(s)"
        )
    while i < len(lines) and (not lines[i].strip() or lines[i].lstrip().startswith("#")):
        i += 1
    if i >= len(lines):
        raise RunFileError(f"{path}: not a readable CSV file (no row of column names)")
    names_line = i + 1  # 1-based, for messages
    if opts.no_header:
        names_line = 0
        names = []
    else:
        names = _split(lines[i], d)
        i += 1
    if opts.layout is not None:
        # fields named by position: the channel's default column name, "" for a skipped one
        names = [DEFAULT_COLUMNS[c] if c else "" for c in opts.layout]
    name_units: list[str | None] = []
    base_names: list[str] = []
    for n in names:
        m = _NAME_UNIT.match(n)
        base_names.append(m.group(1) if m and m.group(1) else n)
        name_units.append(m.group(2) if m and m.group(1) else None)
    row_units: list[str] | None = None
    if opts.units_row:
        if i >= len(lines):
            raise RunFileError(
                f"{path}: --units-row: no row under the names row (line {names_line})"
            )
        row_units = _split(lines[i], d)
        i += 1
    data_rows = [
        (k + 1, ln)
        for k, ln in enumerate(lines[i:], start=i)
        if ln.strip() and not ln.lstrip().startswith("#")
    ]
    if not data_rows:
        raise RunFileError(f"{path}: not a readable CSV file (no data rows after line {i})")
    if text and not text.endswith(("\n", "\r")):
        _check_last_row(path, data_rows, d)

    def find(ch: str, explicit: bool) -> int | None:
        name = opts.columns.get(ch, DEFAULT_COLUMNS[ch])
        for pool in (names, base_names):
            low = [c.lower() for c in pool]
            hits = [k for k, c in enumerate(pool) if c == name] or [
                k for k, c in enumerate(low) if c == name.lower()
            ]
            if len(hits) > 1:
                raise RunFileError(
                    f"{path}: run '{run}': channel '{ch}': column '{name}' appears "
                    f"{len(hits)} times (fields {', '.join(str(k + 1) for k in hits)}); "
                    "rename one, or name the fields with --columns"
                )
            if hits:
                return hits[0]
        if explicit:
            needed = [
                opts.columns.get(c, DEFAULT_COLUMNS[c])
                for c in DEFAULT_COLUMNS
                if c in opts.columns or c in ("time", "position", "force")
            ]
            if opts.layout is not None:
                hint = {
                    "muscle_pressure": "; name the pressure field, or give --pressure MPA "
                    "or --pressure-from-name",
                    "position": "; name the position field, or give the contraction an "
                    "isometric test held: --position MM or --position-from-name",
                }.get(ch, "")
                raise RunFileError(
                    f"{path}: run '{run}': channel '{ch}': not in --columns "
                    f"({', '.join(c or '-' for c in opts.layout)}){hint}"
                )
            raise RunFileError(
                f"{path}: run '{run}': channel '{ch}': no column '{name}' "
                f"(columns: {', '.join(n for n in names[:8] if n)}"
                + (", …" if len(names) > 8 else "")
                + (f" on line {names_line})" if names_line != 1 else ")")
                + (
                    _headerless_hint(names, d)
                    or _header_hint(lines, needed, names_line, d)
                    or _delimiter_hint(names, d)
                )
            )
        return None

    wanted: dict[str, int] = {}
    for ch in DEFAULT_COLUMNS:
        required = (
            ch in ("time", "force")
            or (ch == "position" and opts.position_mm is None)
            or (ch == "muscle_pressure" and opts.pressure_MPa is None)
        )
        col = find(ch, explicit=required or ch in opts.columns)
        if col is not None:
            wanted[ch] = col
    # ---- the numbers: pandas' C parser makes every clean column float at once; a column
    # with a bad cell stays text and is converted cell by cell below to name the cell
    try:
        df = pd.read_csv(
            io.StringIO("\n".join(ln for _, ln in data_rows)),
            sep=r"\s+" if d == " " else d,
            header=None,
            decimal=opts.decimal,
            keep_default_na=False,
            na_values=[],
            skipinitialspace=True,
        )
    except (pd.errors.ParserError, pd.errors.EmptyDataError, ValueError) as exc:
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        m = re.search(r"Expected (\d+) fields in line (\d+), saw (\d+)", first)
        if m and int(m.group(2)) <= len(data_rows):
            raise RunFileError(
                f"{path}: line {data_rows[int(m.group(2)) - 1][0]}: {m.group(3)} fields where the "
                f"rows before have {m.group(1)}; wrong --delimiter or --header-rows?"
            ) from None
        raise RunFileError(f"{path}: not a readable CSV file ({first[:120]})") from None
    extra = df.shape[1] - len(names)
    if extra > 0:
        tail = df.iloc[:, len(names) :]
        if not tail.astype(str).isin(["", "nan"]).all().all():  # a trailing delimiter is harmless
            if opts.layout is not None:
                raise RunFileError(
                    f"{path}: line {data_rows[0][0]}: {df.shape[1]} fields but "
                    f"--columns names {len(names)}; name every field "
                    "('-' skips one) or check --delimiter"
                )
            raise RunFileError(
                f"{path}: line {data_rows[0][0]}: {df.shape[1]} fields but "
                f"{len(names)} column names (line {names_line}); wrong "
                "--delimiter or --header-rows?"
            )
        df = df.iloc[:, : len(names)]

    raw: dict[str, tuple[np.ndarray, str]] = {}
    for ch, col in wanted.items():
        cname = names[col]
        if col >= df.shape[1]:
            raise RunFileError(
                f"{path}: run '{run}': channel '{ch}': column '{cname}' has no "
                f"values (rows have {df.shape[1]} fields)"
            )
        column = df.iloc[:, col]
        values: np.ndarray
        if np.issubdtype(column.dtype, np.number):
            values = column.to_numpy(dtype=np.float64)
        else:
            text = column.fillna("").astype(str).str.strip()
            num = text.str.replace(",", ".", regex=False) if opts.decimal == "," else text
            # a Series in, a Series out (pandas' own annotation is every overload's union)
            numbers = cast("pd.Series", pd.to_numeric(num, errors="coerce"))
            values = numbers.to_numpy(dtype=np.float64)
            bad = np.flatnonzero(np.isnan(values) & (num.str.lower() != "nan").to_numpy())
            if bad.size:
                k = int(bad[0])
                cell = text.iloc[k]
                raise RunFileError(
                    f"{path}: run '{run}': channel '{ch}': column '{cname}' row "
                    f"{data_rows[k][0]} is not a number ({cell!r})" + _cell_hint(cell, k, opts, ch)
                )
        if ch in opts.negate:
            values = -values
        unit = opts.units.get(ch)
        if unit is None and row_units is not None:
            unit = row_units[col] if col < len(row_units) and row_units[col] else None
        if unit is None:
            unit = name_units[col]
        raw[ch] = (values, unit if unit is not None else CANONICAL_UNITS[ch])
    return finish_run(
        path,
        run,
        raw,
        opts,
        "csv import",
        {
            "header_rows": opts.header_rows,
            "delimiter": opts.delimiter,
            "decimal": opts.decimal,
            "encoding": opts.encoding,
            "no_header": opts.no_header,
            "layout": opts.layout,
        },
    )


def finish_run(
    path: str | Path,
    run: str,
    raw: dict[str, tuple[np.ndarray, str]],
    opts: CsvImportOptions,
    source: str,
    details: dict,
) -> Run:
    """Channels read from any export (values, unit as written) → a checked run in canonical
    units: the constant pressure of a file without a pressure channel, the checks of
    :func:`pmalab.runfile.validate_channels` (one line naming file, run and channel), and
    the attributes every imported run carries."""
    if "muscle_pressure" not in raw:
        if opts.pressure_MPa is None:
            raise RunFileError(
                f"{path}: run '{run}': channel 'muscle_pressure': none found; "
                "give --pressure MPA or --pressure-from-name"
            )
        n = len(raw["time"][0])
        raw["muscle_pressure"] = (np.full(n, float(opts.pressure_MPa)), "MPa")
    if "position" not in raw:
        if opts.position_mm is None:
            raise RunFileError(
                f"{path}: run '{run}': channel 'position': none found; give the contraction "
                "an isometric test held: --position MM or --position-from-name"
            )
        n = len(raw["time"][0])
        raw["position"] = (np.full(n, float(opts.position_mm)), "mm")
        held_position: float | None = float(opts.position_mm)
    else:
        held_position = None
    raw, dropped = _duplicate_times(path, run, raw, opts.drop_duplicate_times)
    chans = validate_channels(path, run, raw, units_hint=_csv_units_hint)
    check_import(
        path,
        run,
        chans,
        {c: str(normalize_unit(c, u) or u) for c, (_, u) in raw.items()},
        held_position=held_position is not None,
        pressure_given=opts.pressure_MPa is not None,
    )
    check_health(str(path), run, chans)
    nominal = (
        float(opts.pressure_MPa)
        if opts.pressure_MPa is not None
        else float(np.mean(chans["muscle_pressure"]))
    )
    dt = np.diff(chans["time"])
    attrs = {
        "muscle_pressure_MPa": nominal,
        "waveform": opts.waveform,
        "frequency_Hz": opts.frequency_Hz,
        "sample_rate_Hz": float(1.0 / np.median(dt)),
        "protocol": json.dumps(
            {
                "imported_from": str(path),
                "columns": opts.columns,
                "units": {c: u for c, (_, u) in raw.items()},
                "negate": list(opts.negate),
                **details,
            }
        ),
        "role": "identification",
        "source": source,
        "status": "completed",
    }
    test_type, why = detect_test_type(
        chans["position"],
        chans["muscle_pressure"],
        held_position=held_position is not None,
        pressure_given="muscle_pressure" not in raw or opts.pressure_MPa is not None,
        load_N=opts.load_N,
    )
    if opts.test_type is not None:
        test_type, why = opts.test_type, "--test-type"
    attrs["test_type"] = test_type
    attrs["test_type_from"] = why
    if test_type == "isometric":
        attrs["held_position_mm"] = (
            held_position if held_position is not None else float(np.median(chans["position"]))
        )
    if opts.load_N is not None:
        attrs["load_N"] = float(opts.load_N)
    if dropped:
        attrs["dropped_duplicate_times"] = dropped
    return Run(name=run, attrs=attrs, file=str(path), **chans)


def _duplicate_times(
    path: str | Path, run: str, raw: dict[str, tuple[np.ndarray, str]], drop: bool
) -> tuple[dict[str, tuple[np.ndarray, str]], int]:
    """Samples whose time stamp repeats the one before: dropped (``drop``; the first sample
    of each stamp is kept) or refused with the option that drops them.

    Returns
    -------
    (raw, dropped)
        The channels without the repeated samples, and how many were dropped.  Time going
        backwards is left to :func:`~pmalab.runfile.validate_channels` (never repaired).
    """
    t = np.asarray(raw["time"][0])
    if t.ndim != 1 or t.size < 2 or any(np.shape(v) != t.shape for v, _ in raw.values()):
        return raw, 0  # unequal lengths and the like: refused by the channel checks
    with np.errstate(invalid="ignore"):
        dt = np.diff(t.astype(np.float64))
    same = np.flatnonzero(dt == 0) + 1
    if same.size == 0:
        return raw, 0
    if not drop:
        back = np.flatnonzero(dt < 0)
        if back.size == 0 or back[0] + 1 > same[0]:
            raise RunFileError(
                f"{path}: run '{run}': channel 'time': time stamp repeated at sample "
                f"{int(same[0])} ({same.size} repeat(s) in the file); add "
                "--drop-duplicate-times to drop the repeated samples"
            )
        return raw, 0
    keep = np.ones(t.size, dtype=bool)
    keep[same] = False
    return {c: (np.asarray(v)[keep], u) for c, (v, u) in raw.items()}, int(same.size)


#: a length that moves less than this (mm, peak to peak after the sensor's noise) is held
HELD_POSITION_MM = 0.2
#: a pressure that moves less than this (MPa, 5th to 95th percentile) is held
HELD_PRESSURE_MPA = 0.02


def detect_test_type(
    position: np.ndarray,
    pressure: np.ndarray,
    *,
    held_position: bool = False,
    pressure_given: bool = False,
    load_N: float | None = None,
) -> tuple[str, str]:
    """The test type a record's channels show, and why (one phrase for the import's report).

    Parameters
    ----------
    position, pressure
        Contraction (mm) and muscle pressure (MPa), canonical units.
    held_position
        The contraction was given (``--position``): the length was held.
    pressure_given
        The pressure was given (``--pressure``): it was held.
    load_N
        An isotonic test's load (``--load``).

    Returns
    -------
    (test_type, reason)
        ``isometric`` when the length is held and the pressure moves, ``isobaric`` when the
        pressure is held (within :data:`HELD_PRESSURE_MPA` between its 5th and 95th
        percentile), ``isotonic`` with a load given, else ``free`` (both vary).
    """
    lo, hi = np.percentile(pressure, [5.0, 95.0])
    p_span = float(hi - lo)
    xlo, xhi = np.percentile(position, [5.0, 95.0])
    x_span = float(xhi - xlo)
    if load_N is not None:
        return "isotonic", f"--load {load_N:g} N"
    if held_position:
        if pressure_given:
            return "isobaric", "--position and --pressure both held"
        return "isometric", "contraction given, pressure varies"
    if pressure_given or p_span <= HELD_PRESSURE_MPA:
        return "isobaric", f"pressure held (moves {p_span * 1e3:.0f} kPa)"
    if x_span <= HELD_POSITION_MM:
        return "isometric", f"contraction held (moves {x_span:.2f} mm), pressure varies"
    return "free", f"contraction and pressure both vary ({x_span:.1f} mm, {p_span * 1e3:.0f} kPa)"


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


def _headerless_hint(names: list[str], delimiter: str) -> str:
    """The 'names row' is numbers: a file without one (LabVIEW's spreadsheet export)."""
    fields = names
    if len(names) == 1:
        for sep in ("\t", ";", ",", " "):
            if sep != delimiter and sep in names[0]:
                fields = names[0].split() if sep == " " else names[0].split(sep)
                break
    if fields and all(_is_number(f) for f in fields if f):
        sep = (
            ""
            if fields is names
            else {
                "\t": " --delimiter '\\t'",
                ";": " --delimiter ';'",
                ",": " --delimiter ','",
                " ": " --delimiter space",
            }[next(s for s in ("\t", ";", ",", " ") if s in names[0])]
        )
        layout = ",".join(["time"] + ["-"] * max(len(fields) - 1, 0))
        return (
            f"; the first row is numbers, not names: a file without a names row? "
            f"use --no-header{sep} --columns {layout} (name each field; '-' skips one)"
        )
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


def import_csv(
    csv: str | Path, out: str | Path, opts: CsvImportOptions, *, force: bool = False
) -> Run:
    """Import ``csv`` into a new contract file ``out`` (refuses to overwrite without force)."""
    from pmalab.paths import check_output

    if Path(out).exists() and Path(csv).exists() and os.path.samefile(out, csv):
        raise OutputError(
            f"--out {out}: is the input CSV itself (--force would replace your "
            "data with the run file): give the run file another name"
        )
    check_output(out, force)
    run = read_csv_run(csv, opts)
    write_runs(out, [run], force=force)
    return run


def pressure_from_name(path: str | Path, pattern: str) -> float:
    """The nominal muscle pressure in MPa read off a file name with ``pattern``.

    The pattern's first group is the number; its unit is the text the pattern matches after
    the group (``'(\\d+)bar'`` on ``NAPN_3bar.csv`` → 0.3 MPa).  Without a unit in the
    pattern the number is taken as MPa.

    Parameters
    ----------
    path
        The file whose name (not its folder) is read.
    pattern
        A regular expression with one group around the number (``re.search``).

    Returns
    -------
    float
        The nominal muscle pressure, MPa gauge.

    Raises
    ------
    pmalab.errors.RunFileError
        The name does not match, or the value is no muscle pressure.
    """
    try:
        rx = re.compile(pattern)
    except re.error as exc:
        raise RunFileError(f"--pressure-from-name: not a regular expression ({exc})") from None
    if rx.groups < 1:
        raise RunFileError(
            "--pressure-from-name: the pattern needs a group around the number, e.g. '(\\d+)bar'"
        )
    name = Path(path).name
    m = rx.search(name)
    if m is None:
        raise RunFileError(
            f"{path}: --pressure-from-name {pattern!r} does not match the file name '{name}'"
        )
    try:
        value = float(m.group(1).replace(",", ".").replace("p", "."))
    except ValueError:
        raise RunFileError(
            f"{path}: --pressure-from-name: '{m.group(1)}' is not a number"
        ) from None
    unit_text = name[m.end(1) : m.end()].strip(" _-") or "MPa"
    canon = normalize_unit("muscle_pressure", unit_text)
    if canon is None:
        raise RunFileError(
            f"{path}: --pressure-from-name: unknown pressure unit "
            f"'{unit_text}' after the number (write it in the pattern, "
            f"e.g. '(\\d+)bar', '(\\d+)kPa')"
        )
    mpa = value * UNIT_FACTORS["muscle_pressure"][canon]
    hi = PLAUSIBLE["muscle_pressure"].hi
    if not (math.isfinite(mpa) and 0 < mpa <= hi):
        raise RunFileError(
            f"{path}: --pressure-from-name: {value:g} {canon} is not a muscle "
            f"pressure (> 0 and ≤ {hi:g} MPa)"
        )
    return mpa


def position_from_name(
    path: str | Path, pattern: str, max_contraction_mm: float | None = None
) -> float:
    """The contraction (mm) an isometric record was held at, read off its file name.

    The pattern's first group is the number; the text the pattern matches after the group
    is its unit: mm (the default), m, um, or ``%`` / ``pct`` — percent of the maximum
    contraction, which needs ``max_contraction_mm`` (``--max-contraction``).
    ``'_(\\d+)pct'`` on ``festo10_50pct.txt`` with ``--max-contraction 16`` → 8 mm.
    """
    opt = "--position-from-name"
    try:
        rx = re.compile(pattern)
    except re.error as exc:
        raise RunFileError(f"{opt}: not a regular expression ({exc})") from None
    if rx.groups < 1:
        raise RunFileError(
            f"{opt}: the pattern needs a group around the number, e.g. '(\\d+)mm' or '(\\d+)pct'"
        )
    name = Path(path).name
    m = rx.search(name)
    if m is None:
        raise RunFileError(f"{path}: {opt} {pattern!r} does not match the file name '{name}'")
    try:
        value = float(m.group(1).replace(",", ".").replace("p", "."))
    except ValueError:
        raise RunFileError(f"{path}: {opt}: '{m.group(1)}' is not a number") from None
    unit_text = name[m.end(1) : m.end()].strip(" _-") or "mm"
    if unit_text.lower() in ("%", "pct", "percent"):
        if max_contraction_mm is None:
            raise RunFileError(
                f"{path}: {opt}: '{m.group(0)}' is a percentage of the maximum contraction; "
                "give it in mm with --max-contraction MM"
            )
        mm = value / 100.0 * float(max_contraction_mm)
    else:
        canon = normalize_unit("position", unit_text)
        if canon is None:
            raise RunFileError(
                f"{path}: {opt}: unknown length unit '{unit_text}' after the number "
                "(write it in the pattern, e.g. '(\\d+)mm' or '(\\d+)pct')"
            )
        mm = value * UNIT_FACTORS["position"][canon]
    rule = PLAUSIBLE["position"]
    if not (math.isfinite(mm) and rule.lo <= mm <= rule.hi):
        raise RunFileError(f"{path}: {opt}: {mm:g} mm is not a contraction ({rule.what})")
    return mm


def excitation_frequency(run: Run) -> float:
    """The motion's fundamental frequency: the largest peak of the position's spectrum.

    The mean and a linear trend are removed, a Hann window applied, and the peak refined by
    parabolic interpolation between bins.

    Parameters
    ----------
    run
        A run in canonical units (position mm, time s).

    Returns
    -------
    float
        The frequency, Hz.
    """
    t, x = run.time, run.position
    n = len(t)
    if n < 16:
        raise RunFileError(f"{run.file}: run '{run.name}': --frequency auto: only {n} samples")
    tu = np.linspace(t[0], t[-1], n)
    xu = np.interp(tu, t, x)
    xu = xu - np.polyval(np.polyfit(tu - tu[0], xu, 1), tu - tu[0])
    spec = np.abs(np.fft.rfft(xu * np.hanning(n)))
    fs = (n - 1) / (tu[-1] - tu[0])
    k = int(np.argmax(spec[2:])) + 2  # skip DC and the lowest bin (a window-length trend)
    if k + 1 < len(spec):
        a, b, c = spec[k - 1], spec[k], spec[k + 1]
        den = a - 2 * b + c
        k = k + (0.5 * (a - c) / den if den != 0 else 0.0)
    f = float(k * fs / n)
    if not (math.isfinite(f) and f > 0):
        raise RunFileError(
            f"{run.file}: run '{run.name}': --frequency auto: no periodic motion in the position"
        )
    return f


def split_halves(run: Run) -> list[Run]:
    """Split a record into two runs at its middle sample.

    Parameters
    ----------
    run
        One record.

    Returns
    -------
    list of Run
        ``NAME-a`` (role identification, the first half) and ``NAME-b`` (role validation,
        the second half); every sample is kept in exactly one of them.
    """
    n = len(run.time)
    if n < 40:
        raise RunFileError(f"{run.file}: run '{run.name}': --split-halves: only {n} samples")
    mid = n // 2
    out = []
    for tag, sl, role in (
        ("a", slice(0, mid), "identification"),
        ("b", slice(mid, n), "validation"),
    ):
        attrs = dict(run.attrs, role=role, split=f"half {tag} of '{run.name}'")
        chans = {c: getattr(run, c)[sl] for c in ("time", "position", "force", "muscle_pressure")}
        for c in ("cylinder_pressure", "cylinder_pressure_command", "branch"):
            v = getattr(run, c, None)
            if v is not None:
                chans[c] = v[sl]
        out.append(Run(name=f"{run.name}-{tag}", attrs=attrs, file=run.file, **chans))
    return out


def read_export(path: str | Path, opts: CsvImportOptions) -> list[Run]:
    """The runs of one export, by its kind: TDMS (``.tdms``: one run per group), MATLAB
    (``.mat`` v5 or v7.3), else text (one run)."""
    suffix = Path(path).suffix.lower()
    if suffix == ".tdms":
        from pmalab.acquisition.tdms_import import read_tdms_runs

        return read_tdms_runs(path, opts)
    if suffix == ".mat":
        from pmalab.acquisition.mat_import import read_mat_runs

        return read_mat_runs(path, opts)
    return [read_csv_run(path, opts)]


def read_campaign(
    paths: list[str | Path],
    opts: CsvImportOptions,
    *,
    pressure_pattern: str | None = None,
    position_pattern: str | None = None,
    max_contraction_mm: float | None = None,
    halves: bool = False,
    auto_frequency: bool = False,
    progress=None,
) -> list[Run]:
    """Read the runs of several exports and apply what the file names and the motion say.

    Each run is named by its file's stem (unique; ``opts.run`` must be unset for several
    files) and gets the nominal pressure or held contraction from its name, its frequency
    (``auto_frequency``) and its halves (``halves``).  Nothing is written.

    Parameters
    ----------
    paths
        The exports, read by their suffix: a text file (CSV, TSV, ...) is one run, a TDMS
        or MAT file one run per group or struct.
    opts
        How to read them: columns, units, delimiter, header rows (:class:`CsvImportOptions`).
    pressure_pattern
        A regular expression reading each file's nominal pressure off its name
        (:func:`pressure_from_name`; ``--pressure-from-name``).
    position_pattern
        A regular expression reading each file's held contraction (mm, or % of
        ``max_contraction_mm``) off its name: isometric records (``--position-from-name``).
    max_contraction_mm
        The muscle's maximum contraction, mm, for a pattern that reads a percentage.
    halves
        Split each record into an identification and a held-out half (:func:`split_halves`).
    auto_frequency
        Read each run's frequency off its position's spectrum (:func:`excitation_frequency`).
    progress
        Called as ``progress(path, run)`` after each file is read (``None``: silent).

    Returns
    -------
    list of Run
        The runs in canonical units, in the order of ``paths`` (halves: ``NAME-a``,
        ``NAME-b``).

    Raises
    ------
    pmalab.errors.RunFileError
        One line naming the file and field or channel of the first mistake.
    """
    from dataclasses import replace

    if len(paths) > 1 and opts.run:
        raise RunFileError("--run: names one run; with several files each run is named by its file")
    runs: list[Run] = []
    seen: dict[str, Path] = {}
    for p in paths:
        p = Path(p)
        if p.stem in seen and len(paths) > 1:
            raise RunFileError(f"{p}: same name '{p.stem}' as {seen[p.stem]} (rename one)")
        seen[p.stem] = p
        o = opts
        nominal = None
        if pressure_pattern:
            nominal = pressure_from_name(p, pressure_pattern)
            if opts.pressure_MPa is None:  # the constant pressure of a file without a column
                o = replace(opts, pressure_MPa=nominal)
        held = None
        if position_pattern:
            held = position_from_name(p, position_pattern, max_contraction_mm)
            o = replace(o, position_mm=held)
        got = read_export(p, o)
        if len(paths) > 1 and not opts.run and p.suffix.lower() in (".tdms", ".mat"):
            # several files: runs named by their file (and group/struct when a file has more)
            for run in got:
                run.name = p.stem if len(got) == 1 else f"{p.stem}-{run.name}"
        for run in got:
            if nominal is not None:
                run.attrs["muscle_pressure_MPa"] = nominal
                run.attrs["pressure_from"] = f"file name ({pressure_pattern})"
            if held is not None:
                run.attrs["position_from"] = f"file name ({position_pattern})"
            if auto_frequency:
                run.attrs["frequency_Hz"] = round(excitation_frequency(run), 4)
                run.attrs["frequency_from"] = "position spectrum (--frequency auto)"
            if any(r.name == run.name for r in runs):
                raise RunFileError(
                    f"{p}: run '{run.name}': a run of that name was read from "
                    "another file already (rename one)"
                )
            runs.extend(split_halves(run) if halves else [run])
            if progress is not None:
                progress(p, run)
    return runs


def import_files(
    paths: list[str | Path],
    out: str | Path,
    opts: CsvImportOptions,
    *,
    force: bool = False,
    pressure_pattern: str | None = None,
    position_pattern: str | None = None,
    max_contraction_mm: float | None = None,
    halves: bool = False,
    auto_frequency: bool = False,
    progress=None,
) -> list[Run]:
    """Import several exports into one new campaign file.

    Every file is read and checked before anything is written: a mistake in the last file
    leaves no output behind.

    Parameters
    ----------
    paths
        The exports, read by their suffix: a text file (CSV, TSV, ...) is one run, a TDMS
        or MAT file one run per group or struct.
    out
        The run file to write (HDF5).
    opts
        How to read them: columns, units, delimiter, header rows (:class:`CsvImportOptions`).
    force
        Overwrite an existing ``out``.
    pressure_pattern
        A regular expression reading each file's nominal pressure off its name
        (:func:`pressure_from_name`; ``--pressure-from-name``).
    position_pattern
        A regular expression reading each file's held contraction (mm, or % of
        ``max_contraction_mm``) off its name: isometric records (``--position-from-name``).
    max_contraction_mm
        The muscle's maximum contraction, mm, for a pattern that reads a percentage.
    halves
        Split each record into an identification and a held-out half (:func:`split_halves`).
    auto_frequency
        Read each run's frequency off its position's spectrum (:func:`excitation_frequency`).
    progress
        Called as ``progress(path, run)`` after each file is read (``None``: silent).

    Returns
    -------
    list of Run
        The runs written, in canonical units (time s, position mm contraction positive,
        force N tension positive, pressure MPa gauge).

    Raises
    ------
    pmalab.errors.RunFileError
        One line naming the file and field or channel of the first mistake.
    pmalab.errors.OutputError
        ``out`` exists (without ``force``), or is one of the inputs.
    """
    from pmalab.paths import check_output

    for p in paths:
        if Path(out).exists() and Path(p).exists() and os.path.samefile(out, p):
            what = "the input CSV" if len(paths) == 1 else f"the input file {p}"
            raise OutputError(
                f"--out {out}: is {what} itself (--force would replace your "
                "data with the run file): give the run file another name"
            )
    check_output(out, force)
    runs = read_campaign(
        paths,
        opts,
        pressure_pattern=pressure_pattern,
        position_pattern=position_pattern,
        max_contraction_mm=max_contraction_mm,
        halves=halves,
        auto_frequency=auto_frequency,
        progress=progress,
    )
    write_runs(out, runs, force=force)
    return runs


def read_head(path: str | Path, what: str, n: int) -> bytes:
    """The first ``n`` bytes of an export, or one line: no such file, a directory, or a
    file that cannot be read (``what`` names the expected kind: "TDMS", "MATLAB")."""
    p = Path(path)
    if not p.exists():
        raise RunFileError(f"{p}: no such file")
    if p.is_dir():
        raise RunFileError(f"{p}: is a directory, not a {what} file")
    try:
        with p.open("rb") as fh:
            return fh.read(n)
    except OSError as exc:
        raise RunFileError(f"{p}: cannot read ({exc.strerror or exc})") from None


def match_named(
    names: list[str],
    opts: CsvImportOptions,
    where: str,
    what: str = "channel",
    need_time: bool = True,
) -> dict[str, str]:
    """Channels of a self-describing export (TDMS channels, MATLAB variables) by name.

    The names are the CSV importer's (``--time-col`` ... or the defaults), matched exactly,
    then ignoring case, then without a unit in brackets.  Time, position and force are
    required (time only when ``need_time``), the pressure unless ``--pressure`` is given.
    Returns {channel: the export's name}; a missing one is one line listing what is there.
    """
    base = {}
    for n in names:
        m = _NAME_UNIT.match(n)
        base[n] = m.group(1) if m and m.group(1) else n
    out: dict[str, str] = {}
    for ch in DEFAULT_COLUMNS:
        want = opts.columns.get(ch, DEFAULT_COLUMNS[ch])
        hit = next((n for n in names if n == want), None)
        hit = hit or next((n for n in names if n.lower() == want.lower()), None)
        hit = hit or next((n for n in names if base[n].lower() == want.lower()), None)
        if hit is not None:
            out[ch] = hit
            continue
        required = (
            ch == "force"
            or (ch == "position" and opts.position_mm is None)
            or (ch == "time" and need_time)
            or (ch == "muscle_pressure" and opts.pressure_MPa is None)
            or ch in opts.columns
        )
        if required:
            opt = {"muscle_pressure": "--pressure-col", "cylinder_pressure": "--cylinder-col"}.get(
                ch, f"--{ch}-col"
            )
            shown = ", ".join(names[:12]) + (", …" if len(names) > 12 else "")
            raise RunFileError(
                printable(
                    f"{where}: {what} for '{ch}': no {what} '{want}' "
                    f"({what}s: {shown or 'none'}); name it with {opt} NAME"
                )
            )
    return out
