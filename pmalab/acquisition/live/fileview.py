"""``pmalab view FILE.h5``: the live page on a finished or still-recording run file.

A :class:`FileFollower` thread re-opens the file every ``poll_s`` = 0.2 s (SWMR read, so a file
whose recorder is still writing is read consistently), reads the samples each run gained
since the last poll, converts them to the canonical units (s, mm, N, MPa) and publishes
them to the :class:`Hub` exactly as the live pump does.  When every run has a final status
(completed, aborted, not run) the hub is told the file is complete.
"""

from __future__ import annotations

import json
import sys
import threading
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from pmalab.acquisition.live.hub import Hub
from pmalab.acquisition.live.margins import Margins
from pmalab.acquisition.live.pump import DISPLAY_HZ, safety_text
from pmalab.errors import RunFileError
from pmalab.runfile import FORMAT, UNIT_FACTORS, decode_attr

CHANNELS = (
    ("t", "time"),
    ("x", "position"),
    ("f", "force"),
    ("pm", "muscle_pressure"),
    ("pc", "cylinder_pressure"),
    ("cmd", "cylinder_pressure_command"),
)
DIGITS = {"t": 4, "x": 3, "f": 2, "pm": 4, "pc": 4, "cmd": 4}
POLL_S = 0.2  # the recorder flushes every 0.25 s: polling faster shows nothing new


def open_run_file(path: Path) -> h5py.File:
    """Open for reading while a recorder may still be writing it (SWMR), else plainly;
    refuse what is not a pmalab run file (one line)."""
    if not path.is_file():
        raise RunFileError(f"{path}: no such file")
    try:
        f = h5py.File(path, "r", swmr=True)
    except OSError:
        try:
            f = h5py.File(path, "r")
        except OSError as exc:
            raise RunFileError(
                f"{path}: not a readable HDF5 file ({str(exc).splitlines()[0]})"
            ) from None
    if decode_attr(f.attrs.get("format")) != FORMAT or "runs" not in f:
        f.close()
        raise RunFileError(f"{path}: not a pmalab run file")
    return f


def _dataset(path: Path, run: str, g: h5py.Group, channel: str) -> h5py.Dataset:
    """Channel ``channel`` of run group ``g``, refused (one line) when it is not a dataset."""
    ds = g[channel]
    if not isinstance(ds, h5py.Dataset):
        raise RunFileError(f"{path}: run '{run}': channel '{channel}' is not a dataset")
    return ds


def _run_info(name: str, index: int, n_runs: int, attrs: Any) -> dict[str, Any]:
    a = {k: decode_attr(v) for k, v in attrs.items()}

    def num(key: str) -> float | None:
        v = a.get(key)
        return float(v) if isinstance(v, int | float) and v == v else None

    return {
        "name": name,
        "n_runs": n_runs,
        "role": a.get("role", ""),
        "muscle_pressure_MPa": num("muscle_pressure_MPa"),
        "waveform": a.get("waveform", ""),
        "frequency_Hz": num("frequency_Hz"),
        "cycles": num("cycles"),
        "settle_s": num("settle_s"),
        "ramp_s": num("ramp_s"),
        "steady_start_s": num("steady_start_s") or 0.0,
        "steady_end_s": num("steady_end_s"),
        "duration_s": (num("steady_end_s") or 0.0) + (num("ramp_s") or 0.0) or None,
        "sample_rate_Hz": num("sample_rate_Hz"),
    }


def _status(g: Any) -> str:
    if "status" not in g:
        return "completed"  # imported data: complete as written
    return decode_attr(g["status"][()]).rstrip("\x00 ")


def _timing(g: Any) -> dict[str, float]:
    try:
        fields = json.loads(decode_attr(g["timing"].attrs.get("fields", "[]")))
        return {k: float(v) for k, v in zip(fields, g["timing"][()]) if v == v}
    except (KeyError, TypeError, ValueError):
        return {}


class FileFollower(threading.Thread):
    """Publishes a run file's runs to ``hub`` and follows it while it grows."""

    def __init__(self, path: str | Path, hub: Hub, poll_s: float = POLL_S) -> None:
        super().__init__(name="pmalab-view-follower", daemon=True)
        self.path = Path(path)
        self.hub = hub
        self.poll_s = poll_s
        self.done: dict[int, int] = {}  # samples published per run
        self.t0: dict[int, float] = {}
        self.error: str | None = None
        self._quit = threading.Event()
        self.complete = False
        self.margins: Margins | None = None

    def close(self) -> None:
        self._quit.set()

    def run(self) -> None:
        while not self._quit.is_set():
            try:
                self.poll()
                self.error = None
            except (OSError, KeyError, RunFileError) as exc:  # mid-write or vanished: retry
                error = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
                if error != self.error:  # say it once, not at every poll
                    print(
                        f"pmalab view: warning: {self.path}: {error} (retrying)",
                        file=sys.stderr,
                        flush=True,
                    )
                self.error = error
            if self.complete:
                return
            self._quit.wait(self.poll_s)

    def poll(self) -> None:
        """Read what the file gained; publish it."""
        with open_run_file(self.path) as f:
            if self.margins is None:
                limits = decode_attr(f.attrs.get("limits", ""), parse_json=True)
                self.margins = Margins.from_limits(limits if isinstance(limits, dict) else {})
            runs = f["runs"]
            if not isinstance(runs, h5py.Group):
                raise RunFileError(f"{self.path}: '/runs' is not a group")
            names = list(runs.keys())
            final = True
            newest = -1
            for i, name in enumerate(names):
                g = runs[name]
                if not isinstance(g, h5py.Group):
                    raise RunFileError(f"{self.path}: run '{name}' is not a group")
                status = _status(g)
                if status in ("running", "pending"):
                    final = False
                n = min(
                    (_dataset(self.path, name, g, c).shape[0] for _, c in CHANNELS[:4] if c in g),
                    default=0,
                )
                if n == 0:
                    continue
                newest = i
                if i not in self.done:
                    self.hub.start_run(i, _run_info(name, i, len(names), g.attrs), status)
                    self.done[i] = 0
                    if self.margins is not None:
                        self.margins.reset()
                if n > self.done[i]:
                    self._publish(i, g, self.done[i], n)
                    self.done[i] = n
                if status not in ("running", "pending"):
                    self.hub.end_run(i, status)
            if newest >= 0:
                self.hub.set_status(self._status_of(newest, len(names), runs[names[newest]]))
            if final and newest >= 0:
                self.complete = True
                k = len(self.done)
                self.hub.finish(
                    f"{self.path.name}: complete ({k} run{'s' * (k != 1)} with samples)"
                )

    def _publish(self, i: int, g: Any, n0: int, n1: int) -> None:
        rate = decode_attr(g.attrs.get("sample_rate_Hz", 0)) or 0
        stride = max(1, round(float(rate) / DISPLAY_HZ)) if rate else 1
        # on the run's own sample grid (every stride-th from its first), like the pump
        start = n0 + (-n0) % stride
        pts: dict[str, list[Any]] = {}
        raw: dict[str, np.ndarray] = {}
        for key, ch in CHANNELS:
            if ch not in g:
                pts[key] = [None] * len(range(start, n1, stride))
                continue
            units = decode_attr(g[ch].attrs.get("units"))
            factor = UNIT_FACTORS[ch].get(units)
            if factor is None:
                raise RunFileError(
                    f"{self.path}: run '{g.name}': channel '{ch}': unknown unit {units!r}"
                )
            full = np.asarray(g[ch][n0:n1], dtype=np.float64) * factor
            raw[key] = full
            if key == "t":
                self.t0.setdefault(i, float(full[0]) if n0 == 0 else 0.0)
                full = full - self.t0[i]
            pts[key] = np.round(full[start - n0 :: stride], DIGITS[key]).tolist()
        if self.margins is not None and all(k in raw for k in ("x", "f", "pm")):
            pc = raw.get("pc", np.zeros_like(raw["x"]))
            self.margins.update(raw["x"], raw["f"], raw["pm"], pc)
        self.hub.add_points(i, pts)

    def _status_of(self, i: int, n_runs: int, g: Any) -> dict[str, Any]:
        status = _status(g)
        timing = _timing(g)
        info = self.hub.runs[i].info
        t = float(g["time"][-1]) - self.t0.get(i, 0.0) if g["time"].shape[0] else 0.0
        dur = info.get("duration_s") or t or 1.0
        phase = "recording" if status == "running" else status
        return {
            "run": info["name"],
            "index": i,
            "n_runs": n_runs,
            "t": round(t, 3),
            "duration_s": dur,
            "progress_run": min(1.0, t / dur),
            "progress_protocol": min(1.0, (i + min(1.0, t / dur)) / n_runs),
            "samples": self.done.get(i, 0),
            "late": int(timing.get("late", 0)),
            "missed": int(timing.get("missed", 0)),
            "dropped": 0,
            "phase": phase,
            "message": "" if status in ("running", "completed") else status,
            "safety": safety_text(phase, False),
            "margins": self.margins.rows() if self.margins is not None else [],
        }
