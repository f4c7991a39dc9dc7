"""Self-checking run files: every sample dataset carries HDF5's Fletcher32 checksum and
every run's attributes a SHA-256 digest, so damage is refused in one line naming file, run
and dataset (never read as samples), ``pmalab check`` says what is intact, and files
written before either existed still read.

The fuzz test damages a recorded campaign at random (truncation, bit flips, zeroed 512-byte
blocks, metadata bytes): every copy must be refused in one line or read exactly as the
original (``python -m bench trust`` counts the outcomes over many more copies)."""

from __future__ import annotations

import contextlib
import io
from pathlib import Path

import h5py
import numpy as np
import pytest
from corrupt_runs import KINDS, corrupt, data_ranges, outcome_guarded
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from pmalab.cli import main as pmalab_main
from pmalab.errors import RunFileError
from pmalab.runfile import Run, read_runs, write_runs


def _cli(args) -> tuple[int, str, str]:
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = pmalab_main([str(a) for a in args])
    return code, out.getvalue(), err.getvalue()


def _run(name: str = "r", n: int = 10000) -> Run:
    t = np.arange(n) * 0.002
    x = 12.0 + 8.0 * np.sin(2 * np.pi * 0.5 * t)
    return Run(name=name, time=t, position=x, force=300.0 - 10.0 * x,
               muscle_pressure=np.full(n, 0.4),
               attrs={"muscle_pressure_MPa": 0.4, "frequency_Hz": 0.5, "waveform": "sine"})


PROTOCOL = """
[protocol]
name = "small"
[[run]]
name = "a"
muscle_pressure_MPa = 0.3
waveform = "sine"
frequency_Hz = 0.5
magnitude_MPa = 0.3
cycles = 2
ramp_s = 0.5
settle_s = 0.2
[[run]]
name = "b"
muscle_pressure_MPa = 0.5
waveform = "sine"
frequency_Hz = 0.5
magnitude_MPa = 0.3
cycles = 2
ramp_s = 0.5
settle_s = 0.2
"""


@pytest.fixture(scope="module")
def recorded(tmp_path_factory) -> Path:
    d = tmp_path_factory.mktemp("rec")
    (d / "p.toml").write_text(PROTOCOL)
    code, _, err = _cli(["run", "--rig", "sim", "--protocol", d / "p.toml", "--out",
                         d / "c.h5", "--quiet"])
    assert code == 0, err
    return d / "c.h5"


def _flip(path: Path, offset: int) -> None:
    with open(path, "r+b") as fh:
        fh.seek(offset)
        b = fh.read(1)
        fh.seek(offset)
        fh.write(bytes([b[0] ^ 0x10]))


def _chunk_offset(path: Path, dataset: str) -> int:
    with h5py.File(path, "r") as f:
        return int(f[dataset].id.get_chunk_info(0).byte_offset)


def test_every_sample_dataset_is_checksummed(tmp_path, recorded):
    p = write_runs(tmp_path / "w.h5", [_run()])
    for path in (p, recorded):
        with h5py.File(path, "r") as f:
            for name, g in f["runs"].items():
                for ch in ("time", "position", "force", "muscle_pressure"):
                    assert g[ch].fletcher32 and g[ch].chunks, (path, name, ch)


def test_a_flipped_bit_is_refused_naming_file_run_channel(tmp_path):
    p = write_runs(tmp_path / "w.h5", [_run()])
    _flip(p, _chunk_offset(p, "runs/r/position") + 5000)
    with pytest.raises(RunFileError) as ei:
        read_runs(p)
    msg = str(ei.value)
    assert msg.startswith(f"{p}: run 'r': channel 'position': stored samples damaged")
    assert "checksum" in msg and "\n" not in msg
    code, out, err = _cli(["check", p])
    assert code == 2 and err.count("\n") == 1
    assert "position: samples 0–4095 fail their checksum (4096 of 10000)" in out
    assert "intact (checksums pass): force, muscle_pressure, time" in out


def test_check_says_intact(tmp_path, recorded):
    code, out, err = _cli(["check", recorded])
    assert code == 0, err
    assert "2 of 2 runs intact" in out and "DAMAGED" not in out


def test_changed_attribute_is_refused_and_a_deliberate_edit_can_unseal(tmp_path):
    p = write_runs(tmp_path / "w.h5", [_run()])
    with h5py.File(p, "a") as f:
        f["runs/r"].attrs["frequency_Hz"] = 0.25
    with pytest.raises(RunFileError, match=r"run 'r': attributes changed since written"):
        read_runs(p)
    with h5py.File(p, "a") as f:
        del f["runs/r"].attrs["attrs_sha256"]
    assert read_runs(p)[0].frequency == 0.25


def test_files_written_without_checksums_still_read(tmp_path):
    """A version-1 file as earlier pmalab (and other tools) wrote it: contiguous datasets,
    variable-length text attributes, no digest."""
    p = tmp_path / "old.h5"
    r = _run()
    with h5py.File(p, "w") as f:
        f.attrs["format"] = "pmalab.run"
        f.attrs["format_version"] = 1
        g = f.create_group("runs/r")
        g.attrs.update({"muscle_pressure_MPa": 0.4, "waveform": "sine", "frequency_Hz": 0.5})
        for ch, v in r.channels().items():
            g.create_dataset(ch, data=v).attrs["units"] = {"time": "s", "position": "mm",
                                                          "force": "N"}.get(ch, "MPa")
    (got,) = read_runs(p)
    np.testing.assert_array_equal(got.position, r.position)
    code, out, _ = _cli(["check", p])
    assert code == 0 and "written without checksums" in out


SETTINGS = settings(max_examples=40, deadline=None, derandomize=True,
                    suppress_health_check=[HealthCheck.function_scoped_fixture])


@SETTINGS
@given(kind=st.sampled_from(KINDS), where=st.floats(0.0, 1.0), bit=st.integers(0, 7))
def test_damaged_recording_is_refused_or_read_unchanged(tmp_path, recorded, kind, where, bit):
    original = read_runs(recorded)
    bad = tmp_path / f"bad-{kind}.h5"
    bad.write_bytes(corrupt(recorded.read_bytes(), kind, where, bit, data_ranges(recorded)))
    result, detail = outcome_guarded(original, bad, timeout_s=60)
    assert result in ("refused", "identical", "flagged"), (kind, where, bit, detail)
