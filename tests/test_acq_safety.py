"""Safety: limit trips, Ctrl-C, device faults, exceptions, refused protocols — every exit vents.

Uses the fake rig of ``test_acq_fakes`` (virtual clock, a regulator that records each call
with the clock time), so "vented within one sample period" is checked exactly.
"""

from __future__ import annotations

import numpy as np
import pytest
from test_acq_fakes import TWO_RUNS, make_fake_rig, override_at, raise_at

from pmalab.acquisition.protocol import parse_protocol
from pmalab.acquisition.runner import RunnerOptions, run_protocol
from pmalab.acquisition.safety import ProtocolRefused
from pmalab.errors import OutputExistsError, RigError, SafetyAbort
from pmalab.rig.base import Limits
from pmalab.runfile import read_runs

DT = 1 / 500

PROTO = TWO_RUNS


def _proto(text: str = PROTO):
    return parse_protocol(text, "safety.toml")


def _opts() -> RunnerOptions:
    return RunnerOptions(progress=False)


def test_completed_run_vents_and_records(tmp_path):
    rig = make_fake_rig()
    out = tmp_path / "ok.h5"
    res = run_protocol(rig, _proto(), out, options=_opts())
    assert [r.status for r in res] == ["completed", "completed"]
    reg = rig.cylinder_regulator
    assert reg.calls[-1][1] == "vent"  # the last thing the regulator heard
    assert rig.muscle_supply.vents >= 1
    runs = read_runs(out)
    assert [r.name for r in runs] == ["first", "second"]
    r = runs[0]
    assert r.attrs["status"] == "completed"
    assert len(r) == int(round(r.attrs["steady_end_s"] * 500 + 0.5 * 500)) + 1
    np.testing.assert_allclose(np.diff(r.time), DT, atol=1e-9)
    assert r.cylinder_pressure_command.max() == pytest.approx(0.3, abs=1e-4)
    assert r.attrs["timing"]["missed"] == 0 and r.attrs["timing"]["late"] == 0
    assert rig.muscle_supply.requests == [0.4, 0.5]


@pytest.mark.parametrize(
    "override, needle",
    [
        ({"force": 2500.0}, "force 2500.0 N beyond the load cell's range"),
        ({"force": -2100.0}, "force -2100.0 N beyond"),
        ({"position": 36.0}, "position 36.00 mm outside the travel"),
        ({"position": -6.0}, "position -6.00 mm outside the travel"),
        ({"muscle_pressure": 0.7}, "muscle pressure 0.700 MPa above the limit"),
        ({"cylinder_pressure": 1.0}, "cylinder pressure 1.000 MPa above the limit"),
        ({"force": float("nan")}, "sensor returned NaN"),
    ],
)
def test_limit_trip_vents_within_one_sample_and_keeps_samples(tmp_path, override, needle):
    t_trip = 1.7  # rig-clock time of the first bad sample (inside run "first")
    rig = make_fake_rig(override_at(t_trip, **override))
    out = tmp_path / "trip.h5"
    with pytest.raises(SafetyAbort) as ei:
        run_protocol(rig, _proto(), out, options=_opts())
    msg = str(ei.value)
    assert "\n" not in msg and "run 'first' aborted" in msg and needle in msg
    assert ("cylinder regulator vented (confirmed: fake regulator at 0 MPa); "
            "muscle regulator vented (confirmed: fake supply at 0 MPa)") in msg
    assert "FAILED" not in msg
    reg = rig.cylinder_regulator
    vents = reg.vent_times()
    assert vents, "regulator never vented"
    # first vent in the same sample period as the bad sample, nothing commanded after it
    assert t_trip <= vents[0] < t_trip + DT
    first_vent = next(i for i, c in enumerate(reg.calls) if c[1] == "vent")
    assert all(v == 0.0 for _, _, v in reg.calls[first_vent:])
    # the file is closed, marked aborted with the reason, and keeps every sample
    (r,) = read_runs(out)  # "second" never ran: skipped
    assert r.name == "first"
    assert r.attrs["status"].startswith("aborted: ") and needle in r.attrs["status"]
    np.testing.assert_allclose(np.diff(r.time), DT, atol=1e-9)  # no sample lost
    assert len(r) == int(round(r.time[-1] / DT)) + 1
    ch = next(iter(override))
    if np.isnan(override[ch]):  # a NaN sample is not stored (it would void the file)
        assert np.all(np.isfinite(getattr(r, ch)))
        assert r.time[-1] < t_trip
    else:  # the bad sample itself is kept, and it is the last one
        assert getattr(r, ch)[-1] == pytest.approx(override[ch])
        assert np.all(np.abs(getattr(r, ch)[:-1] - override[ch]) > 1e-6)
        assert r.cylinder_pressure_command[-1] == 0.0
    import h5py

    with h5py.File(out, "r") as f:  # closed cleanly: a plain (non-SWMR) open works
        assert f["runs/second/status"][()].decode().startswith("not run")


@pytest.mark.parametrize(
    "exc, needle, cause",
    [
        (KeyboardInterrupt(), "interrupted (Ctrl-C)", None),
        (RigError("load cell: no response after 3 retries"), "device fault: load cell", RigError),
        (ZeroDivisionError("boom"), "exception: ZeroDivisionError: boom", ZeroDivisionError),
    ],
)
def test_interrupt_fault_exception_vent_and_leave_readable_file(tmp_path, exc, needle, cause):
    t_fault = 2.3
    rig = make_fake_rig(raise_at(t_fault, exc))
    out = tmp_path / "int.h5"
    with pytest.raises(SafetyAbort) as ei:
        run_protocol(rig, _proto(), out, options=_opts())
    assert needle in str(ei.value)
    if cause is not None:
        assert isinstance(ei.value.__cause__, cause)
    vents = rig.cylinder_regulator.vent_times()
    assert vents and t_fault <= vents[0] < t_fault + DT
    (r,) = read_runs(out)
    assert r.attrs["status"] == f"aborted: {needle}" or r.attrs["status"].startswith(
        f"aborted: {needle}")
    assert len(r) > 500  # the samples before the fault are kept
    assert r.attrs["timing"]["n_samples"] == len(r)


def test_interrupt_while_waiting_for_pressure_vents(tmp_path):
    rig = make_fake_rig(raise_at(0.01, KeyboardInterrupt()))
    with pytest.raises(SafetyAbort, match="interrupted"):
        run_protocol(rig, _proto(), tmp_path / "w.h5", options=_opts())
    assert rig.cylinder_regulator.vent_times()
    assert rig.cylinder_regulator.max_commanded == 0.0


@pytest.mark.parametrize(
    "change, needle",
    [
        ("muscle_pressure_MPa = 0.5", None),  # fine: control case
        ("muscle_pressure_MPa = 0.65", "muscle_pressure_MPa' = 0.65 MPa exceeds the rig's "
                                       "muscle limit 0.6 MPa"),
        ("magnitude_MPa = 0.95", "cylinder command peaks at 0.95 MPa"),
    ],
)
def test_unsafe_protocol_refused_before_anything_moves(tmp_path, change, needle):
    # the unsafe value is in the LAST run: nothing of the earlier runs may run either
    third = ('[[run]]\nname = "third"\nmuscle_pressure_MPa = 0.3\nfrequency_Hz = 0.5\n'
             'magnitude_MPa = 0.3\n')
    key = change.split(" =")[0]
    third = "\n".join(change if ln.startswith(key) else ln for ln in third.splitlines())
    text = PROTO + third
    rig = make_fake_rig()
    out = tmp_path / "ref.h5"
    if needle is None:
        run_protocol(rig, _proto(text), out, options=_opts())
        assert rig.cylinder_regulator.max_commanded > 0.25
        return
    with pytest.raises(ProtocolRefused) as ei:
        run_protocol(rig, _proto(text), out, options=_opts())
    msg = str(ei.value)
    assert "\n" not in msg and "run 'third': refused" in msg and needle in msg
    assert rig.cylinder_regulator.max_commanded == 0.0  # never commanded above zero
    assert rig.muscle_supply.requests == []  # muscle never pressurised
    assert rig.sampler.n == 0
    assert not out.exists() and not out.with_name(out.name + ".partial").exists()


def test_regulator_maximum_caps_the_rig_limit(tmp_path):
    rig = make_fake_rig(limits=Limits(max_cylinder_pressure_MPa=0.9))
    rig.cylinder_regulator.max_pressure_MPa = 0.25  # a smaller regulator than the limit
    with pytest.raises(ProtocolRefused, match=r"above the limit 0.25 MPa"):
        run_protocol(rig, _proto(), tmp_path / "cap.h5", options=_opts())


def test_existing_output_needs_force(tmp_path):
    out = tmp_path / "x.h5"
    out.write_bytes(b"precious")
    rig = make_fake_rig()
    with pytest.raises(OutputExistsError, match="use --force"):
        run_protocol(rig, _proto(), out, options=_opts())
    assert out.read_bytes() == b"precious"
    assert rig.cylinder_regulator.max_commanded == 0.0
    run_protocol(rig, _proto(), out, force=True, options=_opts())
    assert [r.name for r in read_runs(out)] == ["first", "second"]


def test_manual_muscle_regulator_prompts_and_waits_for_stable_pressure(tmp_path):
    rig = make_fake_rig(automatic=False, noise=0.001)
    prompts: list[str] = []
    opts = RunnerOptions(progress=False, prompt=prompts.append)
    run_protocol(rig, _proto(), tmp_path / "m.h5", options=opts)
    assert any(p.startswith("run 'first': fake operator asked for 0.4") and "±0.01 MPa" in p
               for p in prompts)
    r = read_runs(tmp_path / "m.h5")[1]
    # recording started only once the (lagging) pressure was within tolerance
    assert abs(r.muscle_pressure[:250].mean() - 0.5) < 0.01


def test_pressure_that_never_settles_aborts_with_vent(tmp_path):
    rig = make_fake_rig(override_at(0.0, muscle_pressure=0.2))
    text = PROTO.replace("cycles = 2\nramp_s", "pressure_timeout_s = 3\ncycles = 2\nramp_s")
    with pytest.raises(SafetyAbort, match=r"did not settle at 0.4 MPa within 3 s"):
        run_protocol(rig, _proto(text), tmp_path / "s.h5", options=_opts())
    assert rig.cylinder_regulator.vent_times()


@pytest.mark.parametrize("sig, needle", [("SIGINT", "interrupted (Ctrl-C)"),
                                         ("SIGTERM", "terminated (SIGTERM)")])
def test_real_signal_is_acted_on_at_the_next_sample(tmp_path, sig, needle):
    """A real SIGINT/SIGTERM (not an exception injected by the sampler) is deferred to the
    top of the sample loop, so the file stays consistent, and still vents within 1 sample.

    The test sets the disposition it tests: a shell's background job inherits SIGINT
    ignored (and the runner rightly keeps an ignored signal ignored)."""
    import signal

    saved = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)}
    signal.signal(signal.SIGINT, signal.default_int_handler)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    try:
        _signal_case(tmp_path, sig, needle)
    finally:
        for s, h in saved.items():
            signal.signal(s, h)


def _signal_case(tmp_path, sig, needle):
    import os
    import signal

    t_sig = 1.9

    def fault(t, n):
        if abs(t - t_sig) < DT / 2:
            os.kill(os.getpid(), getattr(signal, sig))
        return None

    rig = make_fake_rig(fault)
    out = tmp_path / "sig.h5"
    with pytest.raises(SafetyAbort, match=needle.replace("(", r"\(").replace(")", r"\)")):
        run_protocol(rig, _proto(), out, options=_opts())
    vents = rig.cylinder_regulator.vent_times()
    assert vents and t_sig <= vents[0] <= t_sig + DT + 1e-9
    (r,) = read_runs(out)
    assert r.attrs["status"] == f"aborted: {needle}"
    assert len(r) > 100 and np.all(np.diff(r.time) > 0)
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler  # restored
