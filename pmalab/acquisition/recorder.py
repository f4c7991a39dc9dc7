"""Crash-proof incremental HDF5 recording (contract ``pmalab.run`` v1, :mod:`pmalab.runfile`).

Design (why it survives ``kill -9`` at any moment):

1. The file is built under a temporary name (``OUT.h5.partial``) with **everything that
   is not sample data created up front**: root attrs, one group per run of the protocol
   with all its attrs (nominal pressure, waveform, protocol JSON, rig info, calibration,
   software version, ...), every channel dataset (chunked, extent 0, unlimited), a
   fixed-length string dataset ``status`` ("pending"), a float dataset ``timing``
   whose field names are an attr, and a fixed-length string dataset ``device_stats``
   (empty; at the run's end the JSON of the sampler's fault counters, ``stats()``).  Then the file switches to SWMR write mode
   (single-writer/multiple-reader, ``libver="latest"``) and only then is it renamed to
   ``OUT.h5`` (an atomic ``os.replace`` of an open file).  So the output name never
   points at a file that is not already in SWMR mode with its metadata complete; a kill
   before that leaves only the ``.partial`` file (and any older ``OUT.h5`` untouched).
2. In SWMR mode HDF5 orders its metadata writes so that the file on disk is consistent
   at every instant — that is exactly what lets a concurrent reader open it — and a
   ``kill -9`` freezes the file in one of those instants (the kernel keeps what the
   process had written).  No attribute is created or resized after the switch (HDF5
   forbids it in SWMR mode); the end-of-run facts (status, timing statistics) are
   *values* written into the pre-created ``status``/``timing``/``device_stats`` datasets.
3. Samples are buffered in memory and appended (resize + write + ``flush``) at least
   every ``flush_interval_s`` = 0.25 s of wall time, so a kill loses at most the last
   0.25 s (+ one flush) of samples; a flush of ~125 samples × 7 channels costs ~0.1 ms.
   Each flush rewrites the partly filled last chunk of every channel in place; a kill
   inside that write can tear it (new first pages, old checksum), and the readers keep
   the samples the chunk's previous checksum verifies (:func:`pmalab.runfile.read_samples`).
4. A killed file still carries the SWMR "open for write" flag: a plain read-only open
   refuses it, so :func:`pmalab.runfile.read_runs` retries with ``swmr=True``, which
   HDF5 allows exactly for this case; runs never started (``status == "pending"``) are
   skipped, and a run cut mid-way reads as status ``running`` with its samples.

Channel units are the canonical ones (s, mm, N, MPa); ``lateness`` (s, per sample) is an
extra dataset the reader ignores.  Other writers (``pmalab control``) give their own
``channels`` (dataset path in the run's group → units; a path like ``gains/outer_kp``
makes the group) and append blocks with :meth:`RunWriter.extend`; their end-of-run facts
(metrics, the vent's outcome) go, as JSON, into the pre-created, resizable ``summary``
byte dataset (:meth:`RunWriter.set_summary`), which :func:`pmalab.runfile.read_runs`
merges into the run's attrs.
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import shutil
import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any, cast

import numpy as np

from pmalab.channels import Channels
from pmalab.errors import OutputError
from pmalab.paths import output_failure
from pmalab.runfile import (
    CANONICAL_UNITS,
    CHECKSUM,
    FORMAT,
    FORMAT_VERSION,
    create_run_group,
    declare_channels,
    seal_attrs,
)
from pmalab.writer_process import WRITER_ATTR, identity

if TYPE_CHECKING:
    import h5py

#: recorded channels, in the order :meth:`RunWriter.add` takes them
RECORDED = (
    "time",
    "position",
    "force",
    "muscle_pressure",
    "cylinder_pressure",
    "cylinder_pressure_command",
)
#: fields of the per-run ``timing`` dataset (its ``fields`` attr)
#: ``missed_fraction`` = missed / (samples + missed), ``late_fraction`` = late / samples;
#: ``timing_warning`` is 1 when either exceeds ``warn_fraction`` (the run did not keep its
#: rate: the CLI warns), else 0
TIMING_FIELDS = (
    "start_unix_s",
    "n_samples",
    "duration_s",
    "late",
    "missed",
    "lateness_p50_s",
    "lateness_p99_s",
    "lateness_max_s",
    "late_threshold_s",
    "missed_fraction",
    "late_fraction",
    "warn_fraction",
    "timing_warning",
)
STATUS_LEN = 256
#: bytes reserved for the per-run ``device_stats`` JSON (fixed length: no resize in SWMR
#: mode); a Modbus link + ITV + indicator report ~1 kB
DEVICE_STATS_LEN = 8192
CHUNK = 4096
#: per-dataset chunk cache: a recording only appends, so a few chunks are all it ever
#: touches again; HDF5 2.0's default (8 MiB a dataset) kept every chunk written until it
#: was full — a 30-minute 500 Hz run grew the recorder by ~50 MB (measured with psutil)
CHUNK_CACHE_BYTES = 8 * CHUNK * 8


def _attr(v: Any) -> Any:
    """An HDF5-storable attribute value (dicts/lists as JSON text, None as "")."""
    if v is None:
        return ""
    if isinstance(v, dict | list | tuple):
        return json.dumps(v, sort_keys=True, default=str)
    if isinstance(v, Path):
        return str(v)
    return v


def estimated_file_size(samples_per_run: Sequence[int], n_channels: int = len(RECORDED)) -> int:
    """Bytes a recording of runs with these sample counts needs on disk (an upper bound:
    chunks are allocated whole, plus the pre-created metadata); ``n_channels``: the
    recorded channels (the rig's declaration)."""
    per_sample = 8 * n_channels + 4  # float64 channels + float32 lateness
    total = 256 * 1024  # root attrs: protocol and rig file text, provenance
    for n in samples_per_run:
        chunks = max(1, math.ceil(n / CHUNK))
        total += chunks * CHUNK * per_sample + DEVICE_STATS_LEN + 16 * 1024
    return total


def check_free_space(path: str | Path, need_bytes: int) -> None:
    """Refuse (one line) to record into ``path`` when its file system has less room than
    ``need_bytes`` + 10 %: a full disk mid-run loses the run's last samples and its
    status (HDF5 cannot flush), so it is caught before anything moves."""
    p = Path(path)
    where = next((a for a in (p.parent, *p.parents) if a.exists()), Path("."))
    free = shutil.disk_usage(where).free
    if free < need_bytes * 1.1:
        raise OutputError(
            f"{p}: refused: the recording needs about {need_bytes / 1e6:.1f} MB, only "
            f"{free / 1e6:.1f} MB free on {where}"
        )


#: a dataset up to this many samples is read whole for its percentiles
PERCENTILE_WHOLE = 1 << 22
#: samples read at a time (and histogram bins) for the percentiles of a longer one
PERCENTILE_BLOCK = 1 << 20


def dataset_percentiles(ds: Any, n: int, qs: tuple[float, ...]) -> tuple[float, ...]:
    """``np.percentile`` (linear interpolation) of the first ``n`` values of ``ds`` at
    ``qs``, in bounded memory: a run of hours at 10 kHz has hundreds of millions of
    lateness values, which read whole (and sorted) were gigabytes at the run's end.

    Up to :data:`PERCENTILE_WHOLE` values: read whole (as before).  Beyond: three passes of
    :data:`PERCENTILE_BLOCK` values — range, a histogram locating each needed order
    statistic's bin, then only the values in those bins, sorted — the same order statistics,
    interpolated the same way."""
    if n <= PERCENTILE_WHOLE:
        lat = np.asarray(ds[:n], dtype=np.float64)
        return tuple(float(v) for v in np.percentile(lat, list(qs)))

    def blocks():
        for a in range(0, n, PERCENTILE_BLOCK):
            yield np.asarray(ds[a : min(n, a + PERCENTILE_BLOCK)], dtype=np.float64)

    lo, hi = np.inf, -np.inf
    for b in blocks():
        lo, hi = min(lo, float(b.min())), max(hi, float(b.max()))
    if not hi > lo:
        return tuple(lo for _ in qs)
    edges = np.linspace(lo, hi, PERCENTILE_BLOCK + 1)
    counts = np.zeros(PERCENTILE_BLOCK, dtype=np.int64)
    for b in blocks():
        idx = np.clip(np.searchsorted(edges, b, side="right") - 1, 0, PERCENTILE_BLOCK - 1)
        counts += np.bincount(idx, minlength=PERCENTILE_BLOCK)
    cum = np.cumsum(counts)
    ranks = sorted({r for q in qs for r in _order_ranks(q, n)})
    bins = {r: int(np.searchsorted(cum, r, side="right")) for r in ranks}
    wanted = sorted(set(bins.values()))
    picked: dict[int, list[np.ndarray]] = {k: [] for k in wanted}
    for b in blocks():
        idx = np.clip(np.searchsorted(edges, b, side="right") - 1, 0, PERCENTILE_BLOCK - 1)
        for k in wanted:
            picked[k].append(b[idx == k])
    value: dict[int, float] = {}
    for r, k in bins.items():
        vals = np.sort(np.concatenate(picked[k]))
        below = int(cum[k - 1]) if k > 0 else 0
        value[r] = float(vals[r - below])
    out = []
    for q in qs:
        r0, r1 = _order_ranks(q, n)
        t = q / 100.0 * (n - 1) - r0
        a, b_ = value[r0], value[r1]
        out.append(float(a + (b_ - a) * t))
    return tuple(out)


def _order_ranks(q: float, n: int) -> tuple[int, int]:
    """The two order statistics (0-based) the linear percentile ``q`` interpolates."""
    pos = q / 100.0 * (n - 1)
    r0 = int(np.floor(pos))
    return r0, min(n - 1, r0 + 1)


class RunWriter:
    """Appends one run's samples; :meth:`commit` writes and flushes what is buffered."""

    def __init__(self, rec: Recorder, name: str) -> None:
        self._rec = rec
        self.name = name
        # the Recorder made this group and its datasets before SWMR started
        g = cast("h5py.Group", cast("h5py.Group", rec.file["runs"])[name])

        def ds(key: str) -> h5py.Dataset:
            return cast("h5py.Dataset", g[key])

        self.channels = tuple(rec.channels)
        self._ds = [ds(c) for c in self.channels]
        forces = rec.forces
        self._fi = self.channels.index(forces[0]) if forces else None
        self._summary = ds("summary") if "summary" in g else None
        self._late_ds = ds("lateness")
        self._status = ds("status")
        self._timing = ds("timing")
        self._device_stats = ds("device_stats")
        self._gaps = ds("gaps") if "gaps" in g else None
        self._gap_buf: list[tuple[float, float]] = []
        self._buf: list[list[float]] = [[] for _ in self.channels]
        #: samples appended one at a time (rows), turned into columns at the next commit
        self._rows: list[Sequence[float]] = []
        self._late_buf: list[float] = []
        self.n = 0  # samples written to the file
        self.n_late = 0
        self.n_missed = 0
        self.max_lateness = 0.0
        self.start_unix = time.time()
        self.late_threshold_s = 0.0
        #: a run whose missed or late share exceeds this gets ``timing_warning`` = 1
        self.warn_fraction = 0.01
        self._t_first = self._t_last = 0.0
        self._fmin, self._fmax = math.inf, -math.inf

    # hot path: plain list appends (called 500×/s in real time, as fast as possible virtually)
    def append(self, row: Sequence[float], lateness: float) -> None:
        """Buffer one sample: its values in :attr:`channels` order (the rig's declaration:
        time, the sampled channels, the commands) and its lateness (s)."""
        self._rows.append(row)
        self._late_buf.append(lateness)

    def _fold_rows(self) -> None:
        """Move the appended rows into the per-channel buffers (one transpose a commit)."""
        rows = self._rows
        if not rows:
            return
        nch = len(self._buf)
        bad = next((r for r in rows if len(r) != nch), None)
        if bad is not None:
            rows.clear()
            raise ValueError(
                f"run '{self.name}': a sample has {len(bad)} values for {nch} channels "
                f"({', '.join(self.channels)})"
            )
        for buf, col in zip(self._buf, zip(*rows), strict=True):
            buf.extend(col)
        rows.clear()

    def add(
        self, t: float, x: float, f: float, pm: float, pc: float, cmd: float, lateness: float
    ) -> None:
        """One sample of the single-muscle rig's channels (:data:`RECORDED`, in that
        order); :meth:`append` takes any declaration's row."""
        self.append((t, x, f, pm, pc, cmd), lateness)

    def extend(self, columns: Sequence[np.ndarray], lateness: np.ndarray) -> None:
        """Buffer a block of samples: one array per channel (in :attr:`channels` order, equal
        lengths) and the samples' lateness (s)."""
        self._fold_rows()
        for buf, col in zip(self._buf, columns, strict=True):
            buf.extend(np.asarray(col, dtype=np.float64).tolist())
        self._late_buf.extend(np.asarray(lateness, dtype=np.float64).tolist())

    def set_summary(self, doc: dict[str, Any]) -> None:
        """Write the run's end-of-run facts (JSON) into its ``summary`` dataset and flush."""
        if self._summary is None:
            raise ValueError(f"run '{self.name}' has no summary dataset")
        raw = np.frombuffer(
            json.dumps(doc, sort_keys=True, allow_nan=False, default=str).encode("utf-8"),
            dtype=np.uint8,
        )
        self._summary.resize((raw.size,))
        self._summary[:] = raw
        self._rec.file.flush()

    @property
    def force_range(self) -> tuple[float, float]:
        """(min, max) of the force written so far, N (nan, nan when empty)."""
        return (self._fmin, self._fmax) if self.n else (math.nan, math.nan)

    @property
    def buffered(self) -> int:
        return len(self._late_buf)

    def set_status(self, status: str) -> None:
        raw = status.encode("utf-8")[: STATUS_LEN - 1]
        self._status[()] = np.bytes_(raw)

    def set_device_stats(self, stats: dict[str, Any]) -> None:
        """Store the devices' fault counters (JSON) in the run's ``device_stats`` dataset."""
        text = json.dumps(stats, sort_keys=True, separators=(",", ":"), default=str)
        raw = text.encode("utf-8")
        if len(raw) >= DEVICE_STATS_LEN:  # never write a cut (unparsable) JSON text
            raw = json.dumps(
                {
                    "error": f"device stats too long to record ({len(raw)} bytes > "
                    f"{DEVICE_STATS_LEN - 1})"
                }
            ).encode("utf-8")
        self._device_stats[()] = np.bytes_(raw)

    def commit(self) -> None:
        """Append the buffered samples to the datasets and flush the file (SWMR-safe).

        All or nothing: when a write fails (a full disk), every channel is cut back to the
        samples written before, so the run's channels keep equal lengths, and the buffer
        is kept; the error is raised.
        """
        self._fold_rows()
        k = len(self._late_buf)
        if k:
            n0, n1 = self.n, self.n + k
            lat = np.asarray(self._late_buf, dtype=np.float64)
            try:
                for ds, buf in zip(self._ds, self._buf):
                    ds.resize((n1,))
                    ds[n0:n1] = np.asarray(buf, dtype=np.float64)
                self._late_ds.resize((n1,))
                self._late_ds[n0:n1] = lat.astype(np.float32)
            except BaseException:
                for ds in (*self._ds, self._late_ds):
                    with contextlib.suppress(Exception):
                        ds.resize((n0,))
                raise
            if not self.n:
                self._t_first = self._buf[0][0]
            self._t_last = self._buf[0][-1]
            if self._fi is not None:
                fb = self._buf[self._fi]
                self._fmin = min(self._fmin, min(fb))
                self._fmax = max(self._fmax, max(fb))
            for buf in self._buf:
                buf.clear()
            self._late_buf.clear()
            self.n = n1
            self.max_lateness = max(self.max_lateness, float(lat.max()))
        self._commit_gaps()
        self._timing[()] = self._timing_values(final=False)
        self._rec.file.flush()

    def add_gap(self, t_s: float, n_missed: int) -> None:
        """Record a gap: ``n_missed`` samples the device (or the schedule) did not deliver,
        the first of which was due at ``t_s`` (s from the run's first sample).  Written with
        the next commit into the run's ``gaps`` dataset (rows: start s, samples missed)."""
        self._gap_buf.append((float(t_s), float(n_missed)))

    def _commit_gaps(self) -> None:
        if self._gaps is None or not self._gap_buf:
            return
        n0 = self._gaps.shape[0]
        self._gaps.resize((n0 + len(self._gap_buf), 2))
        self._gaps[n0:] = np.asarray(self._gap_buf, dtype=np.float64)
        self._gap_buf.clear()

    def timing(self) -> dict[str, float]:
        """Timing statistics of what was recorded so far (lateness in s)."""
        return dict(zip(TIMING_FIELDS, self._timing_values(final=True).tolist()))

    def _timing_values(self, final: bool) -> np.ndarray:
        dur = float(self._t_last - self._t_first) if self.n else 0.0
        p50 = p99 = np.nan
        if final and self.n:
            # read back from the file: keeping every sample's lateness in memory grew the
            # recorder by 8 bytes a sample (7 MB in a 30-minute run)
            p50, p99 = dataset_percentiles(self._late_ds, self.n, (50.0, 99.0))
        scheduled = self.n + self.n_missed
        missed_frac = self.n_missed / scheduled if scheduled else 0.0
        late_frac = self.n_late / self.n if self.n else 0.0
        warn = float(missed_frac > self.warn_fraction or late_frac > self.warn_fraction)
        return np.array(
            [
                self.start_unix,
                self.n,
                dur,
                self.n_late,
                self.n_missed,
                p50,
                p99,
                self.max_lateness,
                self.late_threshold_s,
                missed_frac,
                late_frac,
                self.warn_fraction,
                warn,
            ],
            dtype=np.float64,
        )

    def finish(self, status: str) -> dict[str, float]:
        """Write remaining samples, final timing statistics and ``status``; flush."""
        self.commit()
        self._timing[()] = self._timing_values(final=True)
        self.set_status(status)
        self._rec.file.flush()
        return self.timing()


class Recorder:
    """The output file of one ``pmalab run``: every run's group made before SWMR starts.

    ``runs`` is a list of ``(name, attrs)``; ``root_attrs`` are written on ``/``.
    ``channels``: the per-sample datasets (path in the run's group → units; default the
    acquisition's :data:`RECORDED` in canonical units); ``summary``: also make each run's
    resizable ``summary`` byte dataset (JSON written at the run's end).
    """

    def __init__(
        self,
        path: str | Path,
        runs: Sequence[tuple[str, dict[str, Any]]],
        root_attrs: dict[str, Any],
        *,
        flush_interval_s: float = 0.25,
        channels: Mapping[str, str] | Channels | None = None,
        summary: bool = False,
    ) -> None:
        import h5py

        self.path = Path(path)
        self.flush_interval_s = flush_interval_s
        #: the declaration written into each run (a rig's channels), or None (a writer's
        #: own datasets, e.g. a controller's gains: units only)
        self.declared: Channels | None = None
        if isinstance(channels, Channels):
            self.declared = channels
            self.channels = channels.units()
        elif channels is None:
            self.channels = {c: CANONICAL_UNITS[c] for c in RECORDED}
        else:
            self.channels = dict(channels)
        self.forces = (
            tuple(c.name for c in self.declared.of_kind("force"))
            if self.declared is not None
            else tuple(c for c in self.channels if c == "force")
        )
        tmp = self.path.with_name(self.path.name + ".partial")
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            f = h5py.File(tmp, "w", libver="latest", rdcc_nbytes=CHUNK_CACHE_BYTES, rdcc_w0=1.0)
        except OSError as exc:
            raise output_failure(self.path, exc, "create the run file") from None
        try:
            f.attrs["format"] = FORMAT
            f.attrs["format_version"] = FORMAT_VERSION
            for k, v in root_attrs.items():
                f.attrs[k] = _attr(v)
            # who writes it: a reader tells a live recording from a killed one
            f.attrs[WRITER_ATTR] = identity()
            seal_attrs(f)
            grp = f.create_group("runs", track_order=True)  # runs read in protocol order
            for name, attrs in runs:
                g = create_run_group(grp, name)
                for k, v in attrs.items():
                    g.attrs[k] = _attr(v)
                for c, units in self.channels.items():
                    ds = g.create_dataset(
                        c,
                        shape=(0,),
                        maxshape=(None,),
                        chunks=(CHUNK,),
                        dtype=np.float64,
                        **CHECKSUM,
                    )
                    ds.attrs["units"] = units
                if self.declared is not None:
                    declare_channels(g, self.declared)
                if summary:
                    ds = g.create_dataset(
                        "summary",
                        shape=(0,),
                        maxshape=(None,),
                        chunks=(CHUNK,),
                        dtype=np.uint8,
                        **CHECKSUM,
                    )
                    ds.attrs["description"] = (
                        "UTF-8 JSON: the run's end-of-run facts (empty until the run ends)"
                    )
                ds = g.create_dataset(
                    "lateness",
                    shape=(0,),
                    maxshape=(None,),
                    chunks=(CHUNK,),
                    dtype=np.float32,
                    **CHECKSUM,
                )
                ds.attrs["units"] = "s"
                ds.attrs["description"] = (
                    "how late the sample was taken after its scheduled time: software-polled, "
                    "the start of its request minus its deadline; hardware-timed, its "
                    "timestamp minus its place on the nominal grid"
                )
                g.create_dataset("status", data=np.bytes_(b"pending"), dtype=f"S{STATUS_LEN}")
                gp = g.create_dataset(
                    "gaps",
                    shape=(0, 2),
                    maxshape=(None, 2),
                    chunks=(64, 2),
                    dtype=np.float64,
                    **CHECKSUM,
                )
                gp.attrs["fields"] = json.dumps(["start_s", "samples_missed"])
                gp.attrs["description"] = (
                    "samples the device or the schedule did not deliver: one row per gap, "
                    "its first missing sample's time (s from the run's first sample) and "
                    "how many; never filled with invented samples"
                )
                t = g.create_dataset(
                    "timing",
                    data=np.full(len(TIMING_FIELDS), np.nan),
                    chunks=(len(TIMING_FIELDS),),
                    **CHECKSUM,
                )
                t.attrs["fields"] = json.dumps(TIMING_FIELDS)
                d = g.create_dataset(
                    "device_stats", data=np.bytes_(b""), dtype=f"S{DEVICE_STATS_LEN}"
                )
                d.attrs["description"] = (
                    "JSON: the devices' link/fault counters at the "
                    "run's end, cumulative since the rig was opened"
                )
                seal_attrs(g)  # the run's and its datasets' attributes are final
            f.flush()
            f.swmr_mode = True  # from here on: no new attrs/objects, only data writes
            os.replace(tmp, self.path)
        except BaseException as exc:
            f.close()
            tmp.unlink(missing_ok=True)
            if isinstance(exc, OSError):  # disk full, a directory in the way, ...
                raise output_failure(self.path, exc, "create the run file") from None
            raise
        self.file = f
        self._last_flush = time.perf_counter()

    def writer(self, name: str) -> RunWriter:
        return RunWriter(self, name)

    def flush_due(self) -> bool:
        """True when ``flush_interval_s`` of wall time passed since the last flush."""
        now = time.perf_counter()
        if now - self._last_flush >= self.flush_interval_s:
            self._last_flush = now
            return True
        return False

    #: True when closing failed (HDF5 could not flush, e.g. a full disk): the library
    #: then holds a file it cannot release and crashes the interpreter at exit
    #: (h5py issues #914, #2160), so the CLI ends such a process with ``os._exit``
    unclosed: bool = False

    def close(self) -> None:
        """Flush and close; the file is closed even when the flush fails (then raised)."""
        f = getattr(self, "file", None)
        if f is not None and f.id.valid:
            try:
                f.flush()
            except BaseException:
                self.unclosed = True
                raise
            finally:
                try:
                    f.close()
                except BaseException:
                    self.unclosed = True
                    raise

    def __enter__(self) -> Recorder:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
