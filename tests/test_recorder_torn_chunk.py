"""A kill during a flush can tear the chunk the recorder was rewriting in place (it appends
into a partly filled chunk, so each flush rewrites it; Linux copies a write page by page and
stops at SIGKILL, leaving the first pages new and the rest, the Fletcher32 checksum stored
last, old).  The file's extent is still the last completed flush's: those samples are intact
and the old checksum verifies them; a killed file reads them, ``recover`` keeps them, and
anything the checksum does not verify is cut and reported, never read as samples."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import h5py
import numpy as np
import pytest

from pmalab.acquisition.check import report
from pmalab.acquisition.recover import recover
from pmalab.errors import RunFileError, RunFileWarning
from pmalab.runfile import Run, fletcher32, read_run_datasets, read_runs
from pmalab.runwindows import LongRuns

REPO = Path(__file__).resolve().parents[1]
N = 5000  # two chunks of 4096: the last holds 904 samples
#: read as a long run, a window at a time (three windows, one across the chunk boundary)


def _joined(w) -> Run:
    """The run read a window at a time and joined (what a windowed reader sees)."""
    parts = [w.read(a, min(a + 1700, len(w))) for a in range(0, len(w), 1700)]
    chans = {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}
    return Run(name=w.name, attrs=dict(w.attrs), file=str(w.path), **chans)


WINDOWED = LongRuns(min_samples=1000, read=_joined)

WRITE = """
import os, sys
import numpy as np
from pmalab.acquisition.recorder import Recorder
n, end = int(sys.argv[2]), sys.argv[3]
rec = Recorder(sys.argv[1], [("a", {"muscle_pressure_MPa": 0.4})], {})
w = rec.writer("a")
w.set_status("running")
rng = np.random.default_rng(7)
for i in range(n):
    w.add(i * 0.002, 10.0 + rng.normal(), 400.0 + 50 * rng.normal(), 0.4, 0.1, 0.1, 0.0)
    if i % 125 == 124:
        w.commit()  # the recorder's 0.25 s flushes at 500 Hz
w.commit()
if end == "killed":
    os._exit(0)  # like kill -9: the file keeps its SWMR "open for write" flag
w.finish("completed")
rec.close()
"""


def _force(n: int) -> np.ndarray:
    rng = np.random.default_rng(7)
    return np.array([(10.0 + rng.normal(), 400.0 + 50 * rng.normal())[1] for _ in range(n)])


def _record(tmp_path: Path, end: str, n: int = N) -> Path:
    out = tmp_path / f"{end}.h5"
    subprocess.run([sys.executable, "-c", WRITE, str(out), str(n), end], check=True,
                   cwd=REPO, env={**os.environ, "PYTHONPATH": str(REPO)}, timeout=120)
    return out


def _chunk(out: Path, start: int) -> tuple[int, int]:
    """File offset and size of the ``force`` chunk holding sample ``start``."""
    with h5py.File(out, "r", swmr=True) if _killed(out) else h5py.File(out, "r") as h:
        info = h["runs/a/force"].id.get_chunk_info_by_coord((start,))
        return int(info.byte_offset), int(info.size)


def _killed(out: Path) -> bool:
    try:
        h5py.File(out, "r").close()
    except OSError:
        return True
    return False


def _write(out: Path, offset: int, data: bytes) -> None:
    with open(out, "r+b") as fh:
        fh.seek(offset)
        fh.write(data)


def _tear(out: Path) -> None:
    """What a kill inside the next flush's write leaves: the last chunk's samples past the
    extent (the next flush's new samples) written, its checksum not."""
    off, _ = _chunk(out, 4096)
    _write(out, off + (N - 4096) * 8, np.linspace(401.0, 420.0, 100).tobytes())


def test_fletcher32_is_hdf5s(tmp_path):
    with h5py.File(tmp_path / "c.h5", "w") as h:
        ds = h.create_dataset("x", data=np.random.default_rng(1).normal(size=777), maxshape=(None,),
                              chunks=(1000,), fletcher32=True)
        _mask, raw = ds.id.read_direct_chunk((0,))
    assert fletcher32(raw[:-4]) == int.from_bytes(raw[-4:], "little")
    assert fletcher32(raw[:-5] + b"\x01") != int.from_bytes(raw[-4:], "little")


def test_a_killed_files_torn_last_chunk_keeps_every_flushed_sample(tmp_path):
    out = _record(tmp_path, "killed")
    _tear(out)
    with h5py.File(out, "r", swmr=True) as h, pytest.raises(OSError):
        h["runs/a/force"][()]  # HDF5 itself refuses the torn chunk
    with pytest.warns(RunFileWarning, match="did not close the file") as rec:
        (run,) = read_runs(out)
    assert not [w for w in rec if "lost" in str(w.message)]  # nothing was lost
    assert run.attrs["status"] == "running" and len(run) == N
    np.testing.assert_array_equal(run.force, _force(N))  # the very samples written
    data = read_run_datasets(out, "a")
    assert {len(v) for v, _ in data.values()} == {N}
    with pytest.warns(RunFileWarning, match="did not close the file"):
        (windowed,) = read_runs(out, long_runs=WINDOWED)
    np.testing.assert_array_equal(windowed.force, _force(N))
    lines, ok = report(out)  # `pmalab check` says what happened, not "damaged"
    assert ok, lines
    assert (f"    torn by the kill: force: its last chunk (samples 4096–{N - 1}) was being "
            "rewritten when the writer was killed; its previous checksum verifies every "
            "flushed sample") in lines
    assert recover(out) == ["a"]  # closed, the chunk rewritten with a fresh checksum
    with h5py.File(out, "r") as h:
        np.testing.assert_array_equal(h["runs/a/force"][()], _force(N))
        assert h["runs/a/status"][()].startswith(b"aborted: recording interrupted")


def test_a_killed_files_unverifiable_last_chunk_is_cut_and_reported(tmp_path):
    out = _record(tmp_path, "killed")
    _tear(out)
    off, _ = _chunk(out, 4096)
    _write(out, off + 8 * 100 + 3, b"\x5a")  # a byte inside the extent: not a tear's work
    with pytest.warns(RunFileWarning) as rec:
        (run,) = read_runs(out)
    lost = [str(w.message) for w in rec if "lost" in str(w.message)]
    assert lost == [f"{out}: run 'a': the last chunk of 'force' (samples 4096..{N - 1}) fails "
                    f"its checksum: torn by the kill that stopped the recording; the run is "
                    f"cut to its first 4096 samples ({N - 4096} lost)"]
    assert len(run) == 4096  # every channel cut to the samples all of them hold
    with pytest.warns(RunFileWarning, match=r"\(904 lost\)"):
        (windowed,) = read_runs(out, long_runs=WINDOWED)
    np.testing.assert_array_equal(windowed.force, _force(4096))
    lines, ok = report(out)
    assert not ok and any(f"DAMAGED: force: samples 4096–{N - 1} fail" in x for x in lines)
    np.testing.assert_array_equal(run.force, _force(4096))
    with pytest.warns(RunFileWarning, match=r"\(904 lost\)"):
        assert recover(out) == ["a"]
    with h5py.File(out, "r") as h:
        assert h["runs/a/force"].shape == h["runs/a/time"].shape == (4096,)


def test_a_damaged_earlier_chunk_of_a_killed_file_is_refused(tmp_path):
    out = _record(tmp_path, "killed")
    off, _ = _chunk(out, 0)
    _write(out, off + 8 * 10 + 3, b"\x5a")  # a long-finished chunk: damage, not a tear
    with pytest.raises(RunFileError, match=r"run 'a'.*'force'.*stored samples damaged"):
        read_runs(out)


def test_a_torn_chunk_in_a_file_that_ended_normally_stays_damaged(tmp_path):
    out = _record(tmp_path, "completed")
    _tear(out)
    with pytest.raises(RunFileError, match=r"run 'a'.*'force'.*stored samples damaged"):
        read_runs(out)


def test_a_killed_files_full_last_chunk_that_fails_is_damage_not_a_tear(tmp_path):
    # 8192 samples: the last chunk was full at the last flush, and no flush rewrites a full
    # chunk, so a failing one cannot be a kill's tear: refused as damaged, never cut
    out = _record(tmp_path, "killed", n=8192)
    off, _ = _chunk(out, 4096)
    _write(out, off + 8 * 100 + 3, b"\x5a")
    with pytest.raises(RunFileError, match=r"run 'a'.*'force'.*stored samples damaged"):
        read_runs(out)
    with pytest.raises(RunFileError, match=r"run 'a'.*'force'.*stored samples damaged"):
        read_runs(out, long_runs=WINDOWED)
