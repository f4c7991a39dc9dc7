"""``pmalab check FILE``: which parts of a run file are intact.

Every sample dataset pmalab writes is chunked with HDF5's Fletcher32 checksum, and every
run's attributes (and its datasets') carry a SHA-256 digest (:func:`pmalab.runfile.attrs_digest`).
The check reads each chunk of each dataset on its own, so a damaged block is located (which
run, which channel, which samples) and everything else is reported intact; then the file
is read as analysis reads it (:func:`pmalab.runfile.read_runs`: units, lengths, time, the
channels' health).  Files written before checksums existed are read and said to be
unverifiable rather than intact.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from pmalab.errors import PmalabError, RunFileError
from pmalab.runfile import (
    DIGEST_ATTR,
    attrs_digest,
    decode_attr,
    is_running,
    open_h5,
    read_runs,
    recording_by,
    rewritten_chunk,
    torn_tail,
)


@dataclass
class RunCheck:
    """What the check found in one run group."""

    name: str
    samples: int = 0
    #: datasets whose every chunk passed its checksum
    intact: list[str] = field(default_factory=list)
    #: datasets stored without a checksum (older files, small metadata datasets)
    unverified: list[str] = field(default_factory=list)
    #: one phrase per damaged dataset or attribute set
    damaged: list[str] = field(default_factory=list)
    #: one phrase per dataset whose last chunk a kill tore mid-rewrite (its flushed
    #: samples verified by the chunk's previous checksum)
    torn: list[str] = field(default_factory=list)
    #: the live writer still recording this run (its words), or "" — such a run is not
    #: checked: its last chunks are rewritten at every flush
    recording: str = ""


def _check_dataset(ds: Any, killed: bool = False) -> tuple[str, str]:
    """("intact" | "torn" | "unverified" | "damaged", detail) of one dataset, chunk by
    chunk; ``killed``: the run's writer died mid-recording (status ``running``), so a
    failed last chunk whose previous checksum verifies its samples is "torn", not damaged
    (:func:`pmalab.runfile.torn_tail`)."""
    if ds.chunks is None or not ds.fletcher32:
        try:
            ds[()]
        except (OSError, RuntimeError, ValueError) as exc:
            return "damaged", f"unreadable ({str(exc).splitlines()[0][:80]})"
        return "unverified", ""
    if ds.ndim == 0 or ds.shape[0] == 0:
        return "intact", ""
    step = ds.chunks[0]
    bad: list[tuple[int, int]] = []
    for start in range(0, ds.shape[0], step):
        stop = min(ds.shape[0], start + step)
        try:
            ds[start:stop]
        except (OSError, RuntimeError, ValueError):
            if bad and bad[-1][1] == start:
                bad[-1] = (bad[-1][0], stop)
            else:
                bad.append((start, stop))
    if not bad:
        return "intact", ""
    n_all = int(ds.shape[0])
    last = rewritten_chunk(ds) if killed else None
    if last is not None and bad == [(last, n_all)] and torn_tail(ds, last, n_all) is not None:
        return "torn", (
            f"its last chunk (samples {last}–{n_all - 1}) was being rewritten when the "
            "writer was killed; its previous checksum verifies every flushed sample"
        )
    spans = ", ".join(f"{a}–{b - 1}" for a, b in bad)
    n = sum(b - a for a, b in bad)
    return "damaged", f"samples {spans} fail their checksum ({n} of {ds.shape[0]})"


def check_file(path: str | Path) -> tuple[list[str], list[RunCheck], str | None]:
    """Check ``path``.

    Returns
    -------
    (file_notes, runs, read_error)
        Notes on the file as a whole (root attributes), one :class:`RunCheck` per run group,
        and the one-line refusal of the analysis reader (None when it reads the file).
    """
    import h5py

    path = Path(path)
    if not path.exists():
        raise RunFileError(f"{path}: no such file")
    if path.is_dir():
        raise RunFileError(f"{path}: is a directory, not a run file")
    notes: list[str] = []
    runs: list[RunCheck] = []
    f = open_h5(path)
    writer = recording_by(f)
    try:
        try:
            want = f.attrs.get(DIGEST_ATTR)
            if want is not None and decode_attr(want) != attrs_digest(f):
                notes.append("file attributes damaged (checksum does not match)")
            runs_g = f.get("runs")
        except (OSError, RuntimeError, KeyError, ValueError) as exc:
            notes.append(f"file metadata damaged ({str(exc).splitlines()[0][:80]})")
            runs_g = None
        if runs_g is None and not notes:
            notes.append("no '/runs' group")
        names: list[str] = []
        if isinstance(runs_g, h5py.Group):
            try:
                names = list(runs_g.keys())
            except (OSError, RuntimeError) as exc:
                notes.append(f"run index damaged ({str(exc).splitlines()[0][:80]})")
        for name in names:
            rc = RunCheck(name)
            runs.append(rc)
            try:
                g = runs_g[name]  # type: ignore[index]
                if not isinstance(g, h5py.Group):
                    rc.damaged.append("not a group")
                    continue
                want = g.attrs.get(DIGEST_ATTR)
                if want is None:
                    rc.unverified.append("attributes")
                elif decode_attr(want) != attrs_digest(g):
                    rc.damaged.append("attributes (checksum does not match)")
                killed = is_running(g)
                if killed and writer is not None:
                    # its live writer rewrites the last chunks at every flush: not checked
                    rc.recording = writer
                    rc.samples = int(getattr(g.get("time"), "shape", (0,))[0])
                    continue
                for key in map(str, g.keys()):
                    ds = g[key]
                    if not isinstance(ds, h5py.Dataset):
                        continue
                    state, detail = _check_dataset(ds, killed)
                    if state == "damaged":
                        rc.damaged.append(f"{key}: {detail}")
                    elif state == "torn":
                        rc.torn.append(f"{key}: {detail}")
                    elif state == "intact":
                        rc.intact.append(key)
                    else:
                        rc.unverified.append(key)
                    if key == "time" and ds.ndim == 1:
                        rc.samples = int(ds.shape[0])
            except (OSError, RuntimeError, KeyError, ValueError) as exc:
                rc.damaged.append(f"metadata ({str(exc).splitlines()[0][:80]})")
    finally:
        f.close()
    read_error = None
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            read_runs(path)
    except PmalabError as exc:
        read_error = str(exc)
    return notes, runs, read_error


def report(path: str | Path) -> tuple[list[str], bool]:
    """The check as lines for the terminal, and whether everything checked is intact."""
    notes, runs, read_error = check_file(path)
    lines = [f"{path}: {n}" for n in notes]
    ok = not notes
    for rc in runs:
        if rc.recording:
            lines.append(
                f"  run '{rc.name}': still being recorded by {rc.recording}, {rc.samples} "
                "samples so far: not checked until it ends"
            )
            if rc.damaged:  # its attributes, sealed before the first sample, were checked
                ok = False
                lines.append(f"  run '{rc.name}': DAMAGED: " + "; ".join(rc.damaged))
        elif rc.damaged:
            ok = False
            lines.append(f"  run '{rc.name}': DAMAGED: " + "; ".join(rc.damaged))
            if rc.intact:
                lines.append(f"    intact (checksums pass): {', '.join(rc.intact)}")
        elif rc.intact or rc.torn:
            extra = " (no checksum: " + ", ".join(rc.unverified) + ")" if rc.unverified else ""
            lines.append(
                f"  run '{rc.name}': intact, {rc.samples} samples; checksums pass on "
                f"{len(rc.intact)} datasets{extra}"
            )
            lines.extend(f"    torn by the kill: {t}" for t in rc.torn)
        else:
            lines.append(
                f"  run '{rc.name}': readable, {rc.samples} samples; written without checksums, "
                "so damage cannot be detected"
            )
    good = sum(not rc.damaged and not rc.recording for rc in runs)
    live = sum(bool(rc.recording) for rc in runs)
    lines.append(
        f"{path}: {good} of {len(runs)} runs intact"
        + (f", {live} still being recorded" if live else "")
        + ("" if read_error is None else f"; the analysis reader refuses it: {read_error}")
    )
    return lines, ok and read_error is None
