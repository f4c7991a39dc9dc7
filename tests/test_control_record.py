"""A control run is recorded while it runs: a killed or interrupted ``pmalab control``
leaves a readable file with the samples so far (real-time subprocess runs, ~2 s each)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import h5py
import numpy as np
import pytest

from pmalab.acquisition.recover import recover
from pmalab.reports.control import load_control_file
from pmalab.runfile import read_run_datasets, read_runs

ROOT = Path(__file__).resolve().parents[1]
#: wall time a kill may lose after the last recorded stamp: the 0.25 s flush interval, plus
#: the 25-sample (0.05 s) check granularity and scheduling slack on a loaded 2-core machine;
#: the isobaric runner's kill test allows the same
MAX_LOSS_S = 1.0


def _start(out: Path) -> subprocess.Popen:
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    return subprocess.Popen(
        [sys.executable, "-m", "pmalab.cli", "control", "--controller", "sn-pid",
         "--reference", "square:0.1Hz:15mm", "--duration", "30", "--real-time",
         "--out", str(out)], env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
        text=True,
        # the disposition the test tests: a shell's background job would hand the child
        # SIGINT ignored (Python then installs no Ctrl-C handler at all)
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))


def _wait_for_samples(proc: subprocess.Popen, out: Path, n_min: int, timeout: float = 60.0
                      ) -> int:
    """Poll the live file (SWMR read) until it holds ``n_min`` samples; return how many."""
    t0 = time.monotonic()
    while time.monotonic() - t0 < timeout:
        assert proc.poll() is None, proc.communicate()
        if out.exists():
            try:
                n = len(read_runs(out)[0])
            except Exception:  # not yet readable (first flush pending)
                n = 0
            if n >= n_min:
                return n
        time.sleep(0.1)
    proc.kill()
    pytest.fail(f"no {n_min} samples in {out} after {timeout} s")


def _lateness_and_missed(out: Path, t_last: float) -> tuple[np.ndarray, int]:
    """The killed run's per-sample lateness (s) and how many deadlines its gap records say
    were missed before ``t_last`` (read as a concurrent SWMR reader would)."""
    lateness = read_run_datasets(out, "sn-pid")["lateness"][0]
    with h5py.File(out, "r", libver="latest", swmr=True) as h:
        gaps = np.asarray(h["runs/sn-pid/gaps"][()], dtype=np.float64).reshape(-1, 2)
    return lateness, int(gaps[gaps[:, 0] <= t_last, 1].sum())


def test_kill_9_mid_run_leaves_the_samples_so_far(tmp_path):
    out = tmp_path / "killed.h5"
    proc = _start(out)
    seen = _wait_for_samples(proc, out, 500)  # ≥ 1 s of the 30 s run recorded
    time.sleep(0.5)
    proc.send_signal(signal.SIGKILL)
    killed_at = time.time()
    proc.wait(10)
    assert proc.returncode == -signal.SIGKILL
    assert not out.with_name(out.name + ".partial").exists()

    run = read_runs(out)[0]  # the contract reader opens the killed file (SWMR read)
    assert run.attrs["status"] == "running" and run.state == "interrupted"
    assert "metrics" not in run.attrs  # written only when a run ends
    n = len(run)
    assert n >= seen and n < 30 * 500
    assert np.all(np.diff(run.time) > 0) and np.all(np.isfinite(run.position))
    # real clock: each sample is stamped at its deadline plus its own lateness, and the
    # deadlines a busy machine missed are recorded as gaps (never invented samples): the
    # last stamp is where the file's own lateness and gap records put it
    assert 0.0 <= run.time[0] < 0.01
    lateness, missed = _lateness_and_missed(out, run.time[-1])
    assert lateness.shape == (n,) and np.all(lateness > -1e-3)
    due = (n - 1 + missed) * 0.002  # the last sample's deadline, s from the first
    assert due - 1e-3 <= run.time[-1] <= due + float(lateness[-1]) + 0.05, (
        run.time[-1], due, lateness[-1], missed)
    # bounded loss: the run started when its writer did; what is missing at the kill is
    # the wall time after the last recorded stamp (missed deadlines are recorded gaps,
    # already inside the stamps, not losses of the kill)
    lost = killed_at - (run.attrs["timing"]["start_unix_s"] + run.time[-1])
    assert lost <= MAX_LOSS_S, lost
    data = read_run_datasets(out, "sn-pid")  # every channel and gain, equal lengths
    assert {"position_reference", "position_setpoint", "gains/outer_kp"} <= set(data)
    assert {len(v) for v, _ in data.values()} == {n}
    f = load_control_file(out)  # what `pmalab report` reads
    assert f.runs[0].status == "running" and f.runs[0].data["position"].size == n
    # `pmalab recover` closes it for other HDF5 tools, gains/ subgroup included
    assert recover(out) == ["sn-pid"]
    with h5py.File(out, "r") as h:
        g = h["runs/sn-pid"]
        assert g["gains/outer_kp"].shape == g["time"].shape == (n,)
        assert g["status"][()].startswith(b"aborted: recording interrupted")


def test_ctrl_c_mid_run_vents_and_the_file_says_aborted(tmp_path):
    out = tmp_path / "interrupted.h5"
    proc = _start(out)
    _wait_for_samples(proc, out, 250)
    proc.send_signal(signal.SIGINT)
    _stdout, stderr = proc.communicate(timeout=30)
    assert proc.returncode != 0
    assert "aborted: interrupted (Ctrl-C)" in stderr and "vented" in stderr, stderr
    assert "Traceback" not in stderr
    run = read_runs(out)[0]
    assert run.attrs["status"] == "aborted: interrupted (Ctrl-C)"
    assert run.attrs["vent_confirmed"] is True
    assert run.attrs["metrics"]["completed"] is False and run.attrs["n_samples"] == len(run)
    assert 250 <= len(run) < 30 * 500


def test_sigterm_mid_run_is_acted_on_at_the_next_sample_vented_samples_kept(tmp_path):
    # the acquisition loop's deferred SIGTERM: the run ends at the next sample, vents,
    # and the file keeps every sample recorded so far with the reason
    out = tmp_path / "terminated.h5"
    proc = _start(out)
    _wait_for_samples(proc, out, 250)
    proc.send_signal(signal.SIGTERM)
    _stdout, stderr = proc.communicate(timeout=30)
    assert proc.returncode != 0
    assert "Traceback" not in stderr
    run = read_runs(out)[0]
    assert run.attrs["status"] == "aborted: terminated (SIGTERM)", run.attrs["status"]
    assert run.attrs["vent_confirmed"] is True
    assert run.attrs["n_samples"] == len(run) >= 250
    assert np.all(np.isfinite(run.position)) and np.all(np.diff(run.time) > 0)
