"""TDMS (LabVIEW's own format) → runs, on the npTDMS package.

Each group of the file is one run, named after the group (with several files, after the file,
``FILE-GROUP`` when a file has several groups).  Channels are found by name as in the CSV
importer (``--time-col`` ... or the defaults ``time``, ``position``, ``force``,
``muscle_pressure``); a channel's unit is ``--units`` if given, else its ``unit_string``
property, else the canonical one.  A group without a time channel takes its time from the
waveform timing of its force channel (``wf_start_offset`` + k·``wf_increment``, s), as
LabVIEW writes waveforms; a group with neither is refused.  Sign convention: position =
contraction; ``--negate position`` flips a DAQ that records elongation.
"""

from __future__ import annotations

import contextlib
from pathlib import Path

import numpy as np

from pmalab.acquisition.csv_import import CsvImportOptions, finish_run, match_named, read_head
from pmalab.errors import RunFileError
from pmalab.runfile import Run


def _open(path: Path):
    from nptdms import TdmsFile

    head = read_head(path, "TDMS", 4)
    if head != b"TDSm":
        raise RunFileError(
            f"{path}: not a TDMS file (no 'TDSm' lead-in; a .tdms_index file or another format?)"
        )
    with _nptdms_messages() as said:
        try:
            f = TdmsFile.read(str(path))
        except Exception as exc:  # npTDMS raises ValueError/KeyError/struct.error on damage
            first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
            raise RunFileError(f"{path}: not a readable TDMS file ({first[:120]})") from None
    if said:
        # npTDMS read past damage (a file cut mid-segment) and would guess the rest
        raise RunFileError(
            f"{path}: a cut or damaged TDMS file ({said[0][:100]}): not imported; its writer "
            "stopped mid-segment or the copy is incomplete"
        )
    return f


@contextlib.contextmanager
def _nptdms_messages():
    """Collect npTDMS's own log lines (it prints them to stderr itself) instead of letting
    them reach the terminal: the caller reports them in one line."""
    import logging

    from nptdms.log import log_manager

    said: list[str] = []

    class Grab(logging.Handler):
        def emit(self, record: logging.LogRecord) -> None:
            said.append(record.getMessage())

    grab = Grab(logging.WARNING)
    loggers = list(log_manager.loggers.values())
    for lg in loggers:
        lg.removeHandler(log_manager.console_handler)
        lg.addHandler(grab)
    try:
        yield said
    finally:
        for lg in loggers:
            lg.removeHandler(grab)
            lg.addHandler(log_manager.console_handler)


def _values(path: Path, group: str, name: str, channel) -> np.ndarray:
    try:
        data = np.asarray(channel[:])
    except Exception as exc:
        raise RunFileError(
            f"{path}: group '{group}': channel '{name}': cannot read its data "
            f"({str(exc)[:100] or type(exc).__name__})"
        ) from None
    if data.dtype.kind not in "iuf":
        raise RunFileError(f"{path}: group '{group}': channel '{name}': not numbers ({data.dtype})")
    return data.astype(np.float64)


def read_tdms_runs(path: str | Path, opts: CsvImportOptions) -> list[Run]:
    """Every group of a TDMS file (with channels) as a run (the module doc says how).

    Parameters
    ----------
    path
        The TDMS file (NI LabVIEW/DIAdem).
    opts
        Which channel is which (by name), units where the channels' ``unit_string`` lacks
        them, ``negate`` (:class:`~pmalab.acquisition.csv_import.CsvImportOptions`).

    Returns
    -------
    list of Run
        One run per group, named after it, in canonical units: time s (from the waveform
        timing when there is no time channel), position mm (contraction positive), force N
        (tension positive), pressure MPa gauge.

    Raises
    ------
    pmalab.errors.RunFileError
        One line naming the file, group and channel.
    """
    path = Path(path)
    f = _open(path)
    groups = [g for g in f.groups() if len(g.channels()) > 0]
    if not groups:
        raise RunFileError(f"{path}: no group with channels")
    if opts.run and len(groups) > 1:
        raise RunFileError(f"--run: names one run, but {path} has {len(groups)} groups")
    runs = []
    for g in groups:
        chans = {c.name: c for c in g.channels()}
        where = f"{path}: group '{g.name}'"
        found = match_named(list(chans), opts, where, need_time=False)
        raw: dict[str, tuple[np.ndarray, str]] = {}
        for ch, name in found.items():
            c = chans[name]
            v = _values(path, g.name, name, c)
            if ch in opts.negate:
                v = -v
            unit = opts.units.get(ch) or c.properties.get("unit_string") or None
            raw[ch] = (v, unit if unit else _canonical(ch))
        if "time" not in raw:
            c = chans[found["force"]]
            inc = c.properties.get("wf_increment")
            if inc is None:
                raise RunFileError(
                    f"{where}: no time channel and no waveform timing "
                    f"(wf_increment) on '{c.name}': name the time channel "
                    "with --time-col NAME"
                )
            try:
                inc = float(inc)
                start = float(c.properties.get("wf_start_offset", 0.0) or 0.0)
            except (TypeError, ValueError):
                raise RunFileError(
                    f"{where}: channel '{c.name}': wf_increment/wf_start_offset are not numbers"
                ) from None
            if not (np.isfinite(inc) and inc > 0):
                raise RunFileError(
                    f"{where}: channel '{c.name}': wf_increment must be > 0 s, got {inc:g}"
                )
            n = len(raw["force"][0])
            raw["time"] = (start + inc * np.arange(n), "s")
        lengths = {ch: len(v) for ch, (v, _) in raw.items()}
        if len(set(lengths.values())) > 1:
            raise RunFileError(
                f"{where}: channels of different lengths "
                f"({', '.join(f'{found.get(k, k)}={n}' for k, n in lengths.items())})"
            )
        name = opts.run or str(g.name)
        runs.append(
            finish_run(path, name, raw, opts, "tdms import", {"group": g.name, "channels": found})
        )
    return runs


def _canonical(ch: str) -> str:
    from pmalab.runfile import CANONICAL_UNITS

    return CANONICAL_UNITS[ch]
