"""Exit paths of the runner not covered by test_acq_safety: a full disk mid-run, failures
while starting, at a run's end, in the operator prompt or the automatic muscle supply, in
preflight and while venting.  Each must vent the cylinder regulator (and the muscle
supply), and leave a file the reader opens with the run marked aborted.
"""

from __future__ import annotations

import errno

import h5py
import numpy as np
import pytest
from test_acq_fakes import TWO_RUNS, make_fake_rig

import pmalab.acquisition.runner as runner_mod
from pmalab.acquisition.protocol import parse_protocol
from pmalab.acquisition.recorder import RunWriter
from pmalab.acquisition.runner import RunnerOptions, run_protocol
from pmalab.errors import OutputError, RigError, SafetyAbort
from pmalab.runfile import read_runs

DT = 1 / 500

def _run(rig, out, **opts):
    return run_protocol(rig, parse_protocol(TWO_RUNS, "paths.toml"), out,
                        options=RunnerOptions(progress=False, **opts))


def _statuses(out):
    with h5py.File(out, "r") as f:  # a plain open: the file was closed cleanly
        return {k: f[f"runs/{k}/status"][()].decode().rstrip("\x00") for k in f["runs"]}


def _assert_vented_last(rig):
    calls = rig.cylinder_regulator.calls
    first_vent = next(i for i, c in enumerate(calls) if c[1] == "vent")
    assert all(v == 0.0 for _, _, v in calls[first_vent:])
    assert calls[-1][1] == "vent" and rig.muscle_supply.vents >= 1


class _FullDisk:
    """An h5py dataset whose writes fail as on a full disk (resizing still works)."""

    def __init__(self, ds):
        self._ds = ds

    def resize(self, shape):
        self._ds.resize(shape)

    def __setitem__(self, key, value):
        raise OSError(errno.ENOSPC, "Can't write data (No space left on device)")


def test_disk_full_mid_run_vents_and_keeps_equal_length_channels(tmp_path, monkeypatch):
    calls = {"n": 0}
    real_commit = RunWriter.commit

    def commit(self):
        calls["n"] += 1
        if calls["n"] == 3 and self.name == "first":  # the disk fills on the 3rd flush
            self._ds[3] = _FullDisk(self._ds[3])  # channels 0..2 written, 3 fails
        return real_commit(self)

    monkeypatch.setattr(RunWriter, "commit", commit)
    rig = make_fake_rig()
    out = tmp_path / "full.h5"
    with pytest.raises(SafetyAbort) as ei:
        _run(rig, out, flush_interval_s=0.0)
    msg = str(ei.value)
    assert "\n" not in msg and "run 'first' aborted" in msg and "No space left" in msg
    _assert_vented_last(rig)
    (r,) = read_runs(out)  # every channel cut back to the same length
    assert r.attrs["status"].startswith("aborted: exception: OSError")
    assert 0 < len(r) == len(r.force) == len(r.cylinder_pressure_command)
    np.testing.assert_allclose(np.diff(r.time), DT, atol=1e-9)
    assert _statuses(out)["second"].startswith("not run")


def _raise(exc):
    def fail(*args, **kwargs):
        raise exc

    return fail


@pytest.mark.parametrize(
    "where, needle, samples",
    [
        # the sampler's stream does not start: before the first sample
        (lambda rig: (rig.sampler, "start"), "device fault: DAQ", 0),
        # the automatic muscle regulator does not answer: before the first sample
        (lambda rig: (rig.muscle_supply, "request"), "device fault: DAQ", 0),
        # after every sample of the run (end-of-run counters): all samples kept
        (lambda rig: (runner_mod, "_store_device_stats"), "device fault: DAQ", 2751),
    ],
    ids=["sampler-start", "muscle-supply", "end-of-run"],
)
def test_a_failing_step_outside_the_sample_loop_aborts_the_run(tmp_path, monkeypatch, where,
                                                                needle, samples):
    rig = make_fake_rig()
    monkeypatch.setattr(*where(rig), _raise(RigError("DAQ: no reply")))
    out = tmp_path / "step.h5"
    with pytest.raises(SafetyAbort, match=f"run 'first' aborted: {needle}"):
        _run(rig, out)
    _assert_vented_last(rig)
    st = _statuses(out)
    assert st["first"].startswith("aborted: device fault") and st["second"].startswith("not run")
    with h5py.File(out, "r") as f:
        assert f["runs/first/force"].shape == (samples,)


def test_exception_in_the_operator_prompt_vents(tmp_path):
    rig = make_fake_rig(automatic=False)

    def prompt(text):
        raise EOFError("no terminal")

    out = tmp_path / "prompt.h5"
    with pytest.raises(SafetyAbort) as ei:
        _run(rig, out, prompt=prompt)
    assert "exception: EOFError: no terminal" in str(ei.value)
    assert ("muscle regulator is manual and NOT vented by software: turn it to 0 MPa and "
            "exhaust the muscle") in str(ei.value)
    _assert_vented_last(rig)
    assert rig.cylinder_regulator.max_commanded == 0.0
    assert _statuses(out)["first"].startswith("aborted: exception: EOFError")


def test_muscle_is_vented_even_when_venting_the_cylinder_fails(tmp_path, monkeypatch, capsys):
    rig = make_fake_rig()
    reg = rig.cylinder_regulator
    real_set = reg.set_pressure

    def set_pressure(mpa):
        if reg.clock.now() > 2.0:
            raise RigError("regulator: link down")
        real_set(mpa)

    def vent():  # a driver breaking the never-raise rule
        raise RigError("regulator: link down")

    monkeypatch.setattr(reg, "set_pressure", set_pressure)
    monkeypatch.setattr(reg, "vent", vent)
    out = tmp_path / "novent.h5"
    with pytest.raises(SafetyAbort, match="device fault: regulator: link down") as ei:
        _run(rig, out)
    msg = str(ei.value)
    assert rig.muscle_supply.vents >= 1
    assert ("cylinder regulator vent FAILED (cylinder regulator vent() raised RigError: "
            "regulator: link down): close the cylinder's supply valve") in msg
    assert "cylinder regulator vented" not in msg
    assert "muscle regulator vented (confirmed" in msg
    assert ei.value.vent.failed == ["cylinder regulator"]
    assert _statuses(out)["first"].startswith("aborted: device fault")
    # the rig's own close also goes on to the muscle and reports (not raises) the failure
    rig.close()
    assert rig.muscle_supply.vents >= 2 and rig.last_vent.failed == ["cylinder regulator"]


class _NoReport:
    """A third-party regulator that returns nothing from vent(): never taken as vented."""

    max_pressure_MPa = 0.9

    def set_pressure(self, mpa):
        pass

    def vent(self):
        return None


def test_a_vent_without_an_outcome_is_reported_failed(tmp_path):
    rig = make_fake_rig()
    rig.cylinder_regulator = _NoReport()
    report = rig.vent()
    assert report.cylinder.outcome.value == "failed"
    assert report.line().startswith("cylinder regulator vent FAILED (cylinder regulator "
                                    "vent() reported no outcome)")


def test_a_later_confirmed_vent_replaces_a_failed_one_in_the_abort_line():
    from pmalab.acquisition.runner import VENT_SLOT, abort_error, update_abort_vent
    from pmalab.rig.base import VentReport, VentResult

    first = VentReport(VentResult.failed("no reply"), VentResult.confirmed("ack"))
    err = abort_error(f"x.h5: run 'a' aborted: boom; {VENT_SLOT}; 3 samples kept", first)
    assert "cylinder regulator vent FAILED (no reply)" in str(err)
    update_abort_vent(err, VentReport(VentResult.confirmed("ack 2"), VentResult.failed("gone")))
    assert str(err) == ("x.h5: run 'a' aborted: boom; cylinder regulator vented (confirmed: "
                        "ack 2); muscle regulator vented (confirmed: ack); 3 samples kept")


def test_exception_in_preflight_vents_and_writes_nothing(tmp_path, monkeypatch):
    def preflight(protocol, rig):
        raise ZeroDivisionError("bad limit arithmetic")

    monkeypatch.setattr(runner_mod, "preflight", preflight)
    rig = make_fake_rig()
    out = tmp_path / "pre.h5"
    with pytest.raises(ZeroDivisionError):
        _run(rig, out)
    assert rig.cylinder_regulator.vent_times() and rig.muscle_supply.vents >= 1
    assert rig.cylinder_regulator.max_commanded == 0.0
    assert not list(tmp_path.iterdir())


def test_full_disk_when_creating_the_file_vents_and_leaves_nothing(tmp_path, monkeypatch):
    def no_space(*a, **k):
        raise OSError(errno.ENOSPC, "Unable to create file")

    monkeypatch.setattr(h5py, "File", no_space)
    rig = make_fake_rig()
    with pytest.raises(OutputError, match=r"x\.h5: cannot create the run file \(No space left"):
        _run(rig, tmp_path / "x.h5")
    assert rig.cylinder_regulator.vent_times() and rig.cylinder_regulator.max_commanded == 0.0
    assert not list(tmp_path.iterdir())


def test_commit_rolls_back_a_partial_write(tmp_path):
    """RunWriter.commit is all-or-nothing: a failed write leaves equal-length channels and
    keeps the buffer, so a later commit writes it once the disk has room again."""
    from pmalab.acquisition.recorder import Recorder

    rec = Recorder(tmp_path / "c.h5", [("a", {})], {})
    w = rec.writer("a")
    for i in range(10):
        w.add(i * DT, 1.0, 2.0, 0.4, 0.1, 0.1, 0.0)
    w.commit()
    for i in range(10, 15):
        w.add(i * DT, 1.0, 2.0, 0.4, 0.1, 0.1, 0.0)
    real = w._ds[4]
    w._ds[4] = _FullDisk(real)
    with pytest.raises(OSError):
        w.commit()
    assert {d.shape[0] for d in (*w._ds[:4], real, w._late_ds)} == {10} and w.n == 10
    w._ds[4] = real
    w.finish("completed")
    rec.close()
    (r,) = read_runs(tmp_path / "c.h5")
    assert len(r) == 15
    np.testing.assert_allclose(r.time, np.arange(15) * DT)


def test_too_little_free_space_is_refused_before_anything_moves(tmp_path, monkeypatch):
    import shutil

    import pmalab.acquisition.recorder as recorder

    usage = shutil.disk_usage(tmp_path)
    monkeypatch.setattr(recorder.shutil, "disk_usage",
                        lambda p: usage._replace(free=300_000))
    rig = make_fake_rig()
    with pytest.raises(OutputError, match=r"x\.h5: refused: the recording needs about 1\.0 MB, "
                                          r"only 0\.3 MB free"):
        _run(rig, tmp_path / "x.h5")
    assert rig.cylinder_regulator.max_commanded == 0.0 and not list(tmp_path.iterdir())


def test_a_file_hdf5_cannot_close_ends_the_cli_with_os_exit(tmp_path, monkeypatch, capsys):
    """On a real full disk HDF5 can flush neither the file nor its status, and crashes
    the interpreter at exit (h5py #914): the abort says so in its one line and the CLI
    leaves with os._exit and the abort's exit code."""
    from pmalab.acquisition.recorder import Recorder

    def flush_fails(self):
        raise RuntimeError("Unable to synchronously flush file (file write failed: "
                           "time = now\n, errno = 28, error message = 'No space left on device')")

    real_commit = RunWriter.commit

    def commit(self):
        if self.n + self.buffered > 600:
            flush_fails(self)
        return real_commit(self)

    monkeypatch.setattr(RunWriter, "commit", commit)
    real_close = Recorder.close

    def close(self):
        self.unclosed = True
        real_close(self)

    monkeypatch.setattr(Recorder, "close", close)
    import pmalab.cli as cli

    def fake_exit(code):
        raise SystemExit(code)

    monkeypatch.setattr(cli.os, "_exit", fake_exit)
    (tmp_path / "p.toml").write_text(TWO_RUNS)
    with pytest.raises(SystemExit) as ei:
        cli.main(["run", "--rig", "sim", "--protocol", str(tmp_path / "p.toml"), "--out",
                  str(tmp_path / "o.h5"), "--quiet"])
    assert ei.value.code == 4
    err = capsys.readouterr().err
    assert err.count("\n") == 1, err
    assert "exception: RuntimeError: No space left on device" in err


def test_both_regulators_are_commanded_before_either_confirmation_waits():
    """An ITV's confirmation waits for its output to fall: the muscle's zero command must
    not wait behind it (Rig.vent commands every regulator first, then confirms)."""
    from pmalab.rig.base import VentResult

    rig = make_fake_rig()
    events = []

    class SlowConfirm(type(rig.cylinder_regulator)):
        def start_vent(self):
            events.append("cylinder commanded")

            def confirm():
                events.append("cylinder confirmation waits")
                return VentResult.confirmed("output fell")

            return confirm

    supply = rig.muscle_supply

    def muscle_vent():
        events.append("muscle commanded")
        return VentResult.confirmed("ack")

    supply.vent = muscle_vent
    rig.cylinder_regulator = SlowConfirm(rig.clock)
    report = rig.vent()
    assert events == ["cylinder commanded", "muscle commanded", "cylinder confirmation waits"]
    assert report.ok and report.cylinder.detail == "output fell"
