"""Damage importer inputs (CSV, TDMS, MAT v5, MAT v7.3) and classify what ``pmalab import``
does: ``python -m bench trust`` counts outcomes; the suite's fuzzing is test_import_robust.py.

Outcomes: ``refused`` (exit 2, one line), ``warned`` (imported, a warning line naming the
problem), ``imported`` (data equal to the clean file's import), ``shorter`` (a text file cut
exactly at a line end: the samples before it, each as written — no reader can tell it from
a shorter export), ``within-noise`` (imported
silently with values changed by less than 5× the channel's noise: no check can see that),
``silent-change`` (changed beyond that, no warning), ``traceback`` (anything else), ``hang``.
"""

from __future__ import annotations

import contextlib
import io
import random
from collections import Counter
from pathlib import Path

import h5py
import numpy as np
import scipy.io
from corrupt_runs import in_child
from nptdms import ChannelObject, GroupObject, TdmsWriter

FORMATS = ("csv", "tdms", "mat5", "mat73")
KINDS = ("truncate", "bitflip", "zero-block")
N = 3000
CHANNELS = ("time", "position", "force", "muscle_pressure")


def signals(seed: int = 0) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(seed)
    t = np.arange(N) * 0.002
    x = 12.0 + 8.0 * np.sin(2 * np.pi * 0.5 * t)
    return {"time": t, "position": x + 0.015 * rng.standard_normal(N),
            "force": 300.0 - 10.0 * x + rng.standard_normal(N),
            "muscle_pressure": 0.4 + 0.001 * rng.standard_normal(N)}


def _v73(path: Path, sig: dict[str, np.ndarray]) -> None:
    with h5py.File(path, "w", userblock_size=512) as f:
        g = f.create_group("run1")
        g.attrs["MATLAB_class"] = np.bytes_("struct")
        for k, v in sig.items():
            g.create_dataset(k, data=np.atleast_2d(v))
    with path.open("r+b") as fh:
        fh.write(b"MATLAB 7.3 MAT-file".ljust(124) + b"\x00\x02IM")


def write(fmt: str, path: Path, sig: dict[str, np.ndarray]) -> None:
    if fmt == "csv":
        path.write_text(",".join(CHANNELS) + "\n" + "\n".join(
            ",".join(f"{sig[c][i]:.6f}" for c in CHANNELS) for i in range(N)) + "\n")
    elif fmt == "tdms":
        with TdmsWriter(str(path)) as w:
            w.write_segment([GroupObject("g")]
                            + [ChannelObject("g", k, v) for k, v in sig.items()])
    elif fmt == "mat5":
        scipy.io.savemat(path, {"run1": sig})
    else:
        _v73(path, sig)


SUFFIX = {"csv": ".csv", "tdms": ".tdms", "mat5": ".mat", "mat73": ".mat"}


def damage(data: bytes, kind: str, where: float, bit: int) -> bytes:
    buf = bytearray(data)
    i = min(len(buf) - 1, int(where * len(buf)))
    if kind == "truncate":
        return bytes(buf[:i])
    if kind == "bitflip":
        buf[i] ^= 1 << bit
        return bytes(buf)
    i = i // 512 * 512
    buf[i : i + 512] = bytes(len(buf[i : i + 512]))
    return bytes(buf)


def _import(src: Path, out: Path) -> tuple[int, str]:
    from pmalab.cli import main

    err = io.StringIO()
    try:
        with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(err):
            code = main(["import", str(src), "--out", str(out), "--force"])
    except BaseException as exc:  # what the harness is for
        return -1, f"{type(exc).__name__}: {exc}"
    return code, err.getvalue()


def _channels(path: Path) -> dict[str, np.ndarray]:
    from pmalab.runfile import read_runs

    (r,) = read_runs(path)[:1]
    return {c: getattr(r, c) for c in CHANNELS}


def classify(src: Path, out: Path, clean: dict[str, np.ndarray]) -> tuple[str, str]:
    code, err = _import(src, out)
    if code == 2 and err.count("\n") == 1 and "Traceback" not in err:
        return "refused", err.strip()
    if code != 0:
        return "traceback", err.strip()[:200]
    got = _channels(out)
    if all(got[c].shape == clean[c].shape and np.array_equal(got[c], clean[c]) for c in CHANNELS):
        return "imported", ""
    if "warning" in err:
        return "warned", err.strip()
    if all(got[c].shape == clean[c].shape for c in CHANNELS):
        from pmalab.health import noise_level

        worst = max(float(np.max(np.abs(got[c] - clean[c])) / max(noise_level(clean[c]), 1e-12))
                    for c in CHANNELS if c != "time")
        dt = float(np.max(np.abs(got["time"] - clean["time"])))
        if worst < 5.0 and dt < 1e-4:
            return "within-noise", f"{worst:.2g} noise levels"
        return "silent-change", f"{worst:.3g} noise levels, time {dt:.3g} s"
    n = got["time"].shape[0]
    if n < clean["time"].shape[0] and all(np.array_equal(got[c], clean[c][:n]) for c in CHANNELS):
        return "shorter", f"{n} of {clean['time'].shape[0]} samples, each as recorded"
    return "silent-change", "lengths differ"


def classify_guarded(src: Path, out: Path, clean, timeout_s: float = 60.0) -> tuple[str, str]:
    """:func:`classify` in a child process (a hang or a dying importer is an outcome)."""
    return in_child(classify, (src, out, clean), "importer", timeout_s)


def import_outcomes(d: Path, n: int, seed: int = 0) -> tuple[Counter, list[str]]:
    """Each format's clean file damaged ``n`` times (the kinds in turn), imported, classified."""
    rng = random.Random(seed)
    counts: Counter = Counter()
    odd: list[str] = []
    for fmt in FORMATS:
        good = d / f"good-{fmt}{SUFFIX[fmt]}"
        write(fmt, good, signals())
        assert _import(good, d / f"clean-{fmt}.h5")[0] == 0, fmt
        clean = _channels(d / f"clean-{fmt}.h5")
        data = good.read_bytes()
        for k in range(n):
            kind = KINDS[k % len(KINDS)]
            bad = d / f"bad-{fmt}{SUFFIX[fmt]}"
            bad.write_bytes(damage(data, kind, rng.random(), rng.randrange(8)))
            res, detail = classify_guarded(bad, d / f"out-{fmt}.h5", clean)
            counts[(fmt, res)] += 1
            if res in ("silent-change", "traceback", "hang"):
                odd.append(f"{fmt} {kind} #{k}: {res}: {detail[:150]}")
    return counts, odd
