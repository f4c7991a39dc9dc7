"""Channel health before any fit: a stuck stretch (a zeroed block, a frozen link) or a
single-sample spike (a flipped bit) is refused in one line naming file, run, channel and
sample — in an import and in a run file without checksums alike.  Calibration over many
simulated seeds and the shipped real records: ``python -m bench trust``."""

from __future__ import annotations

import contextlib
import io

import h5py
import numpy as np
import pytest

from pmalab.cli import main as pmalab_main
from pmalab.errors import RunFileError
from pmalab.health import check_health
from pmalab.runfile import read_runs


def _cli(args) -> tuple[int, str]:
    err = io.StringIO()
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(err):
        code = pmalab_main([str(a) for a in args])
    return code, err.getvalue()


def _chans(n: int = 5000, seed: int = 0) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(seed)
    t = np.arange(n) * 0.002
    x = 12.0 + 8.0 * np.sin(2 * np.pi * 0.5 * t)
    return {"time": t, "position": np.round(x + 0.015 * rng.standard_normal(n), 4),
            "force": np.round(300.0 - 10.0 * x + rng.standard_normal(n), 3),
            "muscle_pressure": np.round(0.4 + 0.001 * rng.standard_normal(n), 4)}


@pytest.mark.parametrize("seed", range(20))
def test_clean_noisy_channels_pass(seed):
    check_health("f.h5", "r", _chans(seed=seed))


@pytest.mark.parametrize("channel", ["position", "force"])
def test_a_zeroed_block_is_refused(channel):
    c = _chans()
    c[channel][1000:1064] = 0.0  # 512 bytes of float64 zeros
    with pytest.raises(RunFileError, match=rf"channel '{channel}': stuck at 0 for 64 samples "
                                           r"from sample 1000"):
        check_health("f.h5", "r", c)


def test_a_frozen_link_repeating_its_last_value_is_refused():
    c = _chans()
    c["force"][3000:3040] = c["force"][2999]
    with pytest.raises(RunFileError, match=r"channel 'force': stuck at .* for 41 samples from sample 2999"):
        check_health("f.h5", "r", c)


def test_a_flipped_bit_spike_is_refused():
    c = _chans()
    c["position"][250] /= 2.0  # an exponent bit: 20 mm reads 10 mm
    with pytest.raises(RunFileError, match=r"channel 'position': sample 250 jumps"):
        check_health("f.h5", "r", c)


def test_fast_real_motion_is_not_a_spike():
    """A 20 mm step in 10 ms (2 m/s) and a force jumping at a reversal are motion."""
    c = _chans()
    c["position"][2500:] += np.minimum(np.arange(c["time"].size - 2500), 5) * 4.0
    c["force"][3000:] -= 150.0
    check_health("f.h5", "r", c)


def test_a_coarse_pressure_gauge_may_repeat():
    c = _chans()
    c["muscle_pressure"] = np.round(c["muscle_pressure"], 2)  # 10 kPa steps: long repeats
    check_health("f.h5", "r", c)


def test_import_and_old_run_file_refuse_a_zeroed_block(tmp_path):
    c = _chans()
    c["position"][1000:1064] = 0.0
    src = tmp_path / "rec.csv"
    src.write_text("time,position,force,muscle_pressure\n" + "\n".join(
        ",".join(f"{c[k][i]:.6g}" for k in ("time", "position", "force", "muscle_pressure"))
        for i in range(c["time"].size)) + "\n")
    code, err = _cli(["import", src, "--out", tmp_path / "o.h5"])
    assert code == 2 and err.count("\n") == 1 and "stuck at 0 for 64 samples" in err
    old = tmp_path / "old.h5"  # written without checksums, as before they existed
    with h5py.File(old, "w") as f:
        f.attrs["format"] = "pmalab.run"
        f.attrs["format_version"] = 1
        g = f.create_group("runs/r")
        g.attrs["muscle_pressure_MPa"] = 0.4
        for k, u in (("time", "s"), ("position", "mm"), ("force", "N"), ("muscle_pressure", "MPa")):
            g.create_dataset(k, data=c[k]).attrs["units"] = u
    with pytest.raises(RunFileError, match=r"run 'r': channel 'position': stuck at 0"):
        read_runs(old)
