"""The NI-DAQmx backend against a strict fake of the ``nidaqmx`` package (tests/fake_nidaqmx).

NI's driver cannot run here; the fake has nidaqmx-python's names and signatures, refuses
what the real driver refuses, and is wired to pmalab's simulated muscle rig (sensors as
volts on ai0-ai3, the regulators' commands on ao0/ao1).  ``pmalab run`` with
``data/rigs/nidaqmx.toml`` records the seed protocol with the same run-file contract as the
simulated rig, time stamps from the sample clock (t = k / rate exactly), and each DAQmx
error path ends in a safe abort: samples kept, the vent confirmed by the pressure falling
or reported FAILED, the line naming the DAQmx code.
"""

from __future__ import annotations

import contextlib
import io
import sys
from pathlib import Path

import h5py
import numpy as np
import pytest

from pmalab.cli import main as pmalab_main
from pmalab.paths import RIGS_DIR
from pmalab.rig.sim.physics import RigPhysics
from pmalab.runfile import decode_attr

FAKE = Path(__file__).resolve().parent / "fake_nidaqmx"
RIG = RIGS_DIR / "nidaqmx.toml"

# the rig file's calibrations, inverted by hand: volts = a * value + b
WIRING_AI = {"ai0": ("muscle_pressure", 4.0, 1.0), "ai1": ("cylinder_pressure", 4.0, 1.0),
             "ai2": ("position", 0.2, 2.0), "ai3": ("force", 1 / 250, 0.0)}
WIRING_AO = {"ao0": ("cylinder", 0.09, 0.0), "ao1": ("muscle", 0.09, 0.0)}


@pytest.fixture
def fake(monkeypatch):
    """The fake package on sys.path (fresh), and one simulated device 'Dev1'."""
    for m in [m for m in sys.modules if m == "nidaqmx" or m.startswith("nidaqmx.")]:
        monkeypatch.delitem(sys.modules, m)
    monkeypatch.syspath_prepend(str(FAKE))
    from nidaqmx import _device

    dev = _device.install(_device.FakeDevice("Dev1", RigPhysics(None, seed=3), WIRING_AI,
                                             WIRING_AO))
    yield dev
    _device.uninstall()


def _run(args: list[str]) -> tuple[int, str, str]:
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = pmalab_main([str(a) for a in args])
    return code, out.getvalue(), err.getvalue()


def test_without_the_package_the_rig_says_what_to_install(tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "nidaqmx", None)  # import fails
    code, _, err = _run(["run", "--rig", RIG, "--protocol", "quick", "--out", tmp_path / "x.h5"])
    assert code != 0 and "needs NI's driver" in err and "pip install" in err
    assert "Traceback" not in err and not (tmp_path / "x.h5").exists()


def test_records_the_quick_protocol_on_the_sample_clock_with_the_sim_rigs_contract(fake, tmp_path):
    out = tmp_path / "ni.h5"
    code, _text, err = _run(["run", "--rig", RIG, "--protocol", "quick", "--out", out, "--quiet"])
    assert code == 0, err
    sim = tmp_path / "sim.h5"
    assert _run(["run", "--rig", "sim", "--protocol", "quick", "--out", sim, "--quiet"])[0] == 0
    with h5py.File(out) as f, h5py.File(sim) as g:
        assert decode_attr(f.attrs["time_base"]) == "device sample clock"
        assert decode_attr(g.attrs["time_base"]) == "virtual clock"
        (name,) = list(f["runs"])
        a, b = f["runs"][name], g["runs"][name]
        assert set(a) == set(b)  # same datasets
        assert set(a.attrs) - {"device_stats"} >= set(b.attrs) - {"device_stats"}
        for ds in ("time", "position", "force", "muscle_pressure"):
            assert a[ds].attrs.get("units") == b[ds].attrs.get("units")
        t = a["time"][:]
        rate = float(f.attrs["sample_rate_Hz"])
        # k / rate from the run's first sample: no host jitter (a host clock shows µs-ms)
        np.testing.assert_allclose(t, np.arange(len(t)) / rate, rtol=0, atol=1e-12)
        assert len(t) == len(b["time"])  # every sample of the protocol, none missed
        # the muscle answered the regulator: force follows the commanded cylinder pressure
        x = a["position"][:]
        assert np.ptp(x) > 5.0 and np.ptp(a["force"][:]) > 100.0
    from pmalab.runfile import read_runs

    assert [r.state for r in read_runs(out)] == ["completed"]
    # the regulators were left at 0 V
    assert fake.ao_volts == {"ao0": 0.0, "ao1": 0.0}


@pytest.mark.parametrize("kind,code,meaning,vent", [
    ("overflow", -200279, "buffer overflow", "vented (confirmed: 0 V written"),
    ("timeout", -200284, "timeout", "vented (confirmed: 0 V written"),
    ("removed", -201003, "device cannot be accessed", "vent FAILED (0 V write"),
])
def test_daqmx_errors_abort_safely_keep_the_samples_and_name_the_code(fake, tmp_path, kind, code,
                                                                      meaning, vent):
    fake.inject(kind, at_sample=1500)
    out = tmp_path / "abort.h5"
    rc, _, err = _run(["run", "--rig", RIG, "--protocol", "quick", "--out", out, "--quiet"])
    assert rc == 4, err
    line = next(ln for ln in err.splitlines() if "aborted" in ln)
    assert f"DAQmx error {code} ({meaning}" in line, line
    assert "Traceback" not in err
    assert line.count(vent) == 2, line  # both regulators
    if kind == "removed":
        assert "confirmed" not in line  # a removed device confirms nothing: never claimed
    else:  # confirmed by the pressure sensors reading the fall, not by the write alone
        assert line.count("_pressure reads") == 2, line
    from pmalab.runfile import read_runs

    (r,) = read_runs(out)
    assert r.state == "aborted"
    assert len(r.time) > 500  # the samples read before the error are kept


def test_the_fake_is_strict_like_the_driver(fake):
    import nidaqmx
    from nidaqmx.constants import AcquisitionType
    from nidaqmx.errors import DaqError
    from nidaqmx.stream_readers import AnalogMultiChannelReader

    task = nidaqmx.Task()
    task.ai_channels.add_ai_voltage_chan("Dev1/ai0", min_val=0.0, max_val=10.0)
    task.timing.cfg_samp_clk_timing(1000.0, sample_mode=AcquisitionType.CONTINUOUS,
                                    samps_per_chan=50)
    reader = AnalogMultiChannelReader(task.in_stream)
    buf = np.zeros((1, 10))
    with pytest.raises(DaqError) as e:
        reader.read_many_sample(buf, 10)  # before start
    assert e.value.error_code == -200473
    with pytest.raises(DaqError) as e:
        task.start()  # 50 samples at 1 kHz: too small a buffer
    assert e.value.error_code == -200608
    with pytest.raises(DaqError) as e:
        task.ai_channels.add_ai_voltage_chan("Dev1/ai99")
    assert e.value.error_code == -200170
    with pytest.raises(DaqError) as e:
        task.timing.cfg_samp_clk_timing(1e7, sample_mode=AcquisitionType.CONTINUOUS)
    assert e.value.error_code == -200077
    task.close()
    ao = nidaqmx.Task()
    ao.ao_channels.add_ao_voltage_chan("Dev1/ao0", min_val=0.0, max_val=10.0)
    ao.close()
    with pytest.raises(DaqError) as e:
        ao.write(1.0)  # a closed task
    assert e.value.error_code == -200088


def test_rig_file_mistakes_are_one_line(fake, tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text(RIG.read_text().replace('channel = "ai3"', 'channel = "ai77"'))
    code, _, err = _run(["run", "--rig", bad, "--protocol", "quick", "--out", tmp_path / "x.h5"])
    assert code == 2 and "DAQmx error -200170" in err and "[rig.inputs]" in err, err
    bad.write_text(RIG.read_text().replace('terminal = "DIFF"', 'terminal = "BALANCED"'))
    code, _, err = _run(["run", "--rig", bad, "--protocol", "quick", "--out", tmp_path / "x.h5"])
    assert code == 2 and "[rig.inputs.force].terminal" in err, err
    assert not (tmp_path / "x.h5").exists()


def test_the_sample_clock_follows_the_protocol_and_an_impossible_rate_is_refused(fake, tmp_path):
    proto = tmp_path / "p.toml"
    text = (RIGS_DIR.parent / "protocols" / "quick.toml").read_text()
    proto.write_text(text.replace('name = "quick"\n', 'name = "quick"\nsample_rate_Hz = 2000\n', 1))
    out = tmp_path / "fast.h5"
    code, _, err = _run(["run", "--rig", RIG, "--protocol", proto, "--out", out, "--quiet"])
    assert code == 0, err
    with h5py.File(out) as f:
        (g,) = f["runs"].values()
        t = g["time"][:]
    np.testing.assert_allclose(np.diff(t), 1 / 2000, rtol=0, atol=1e-12)
    proto.write_text(text.replace('name = "quick"\n', 'name = "quick"\nsample_rate_Hz = 2e5\n', 1))
    code, _, err = _run(["run", "--rig", RIG, "--protocol", proto, "--out", tmp_path / "x.h5"])
    # refused at load, before the card is touched: the protocol's own range check (the
    # rig's 1–100000 Hz limit is the same range, so the protocol's check answers first)
    assert code == 2 and "sample_rate_Hz" in err and "100000" in err and err.count("\n") == 1
    assert not (tmp_path / "x.h5").exists()


@pytest.mark.slow
def test_records_the_seed_protocol_with_the_simulated_rigs_contract(fake, tmp_path):
    """The Bouc-Wen seed paper's campaign (9 runs, 225 s of rig time) through the NI backend:
    the same runs, datasets, units and sample counts as the simulated rig's file."""
    from pmalab.runfile import read_runs

    ni, sim = tmp_path / "ni.h5", tmp_path / "sim.h5"
    code, _, err = _run(["run", "--rig", RIG, "--protocol", "seed-bouc-wen", "--out", ni, "-q"])
    assert code == 0, err
    assert _run(["run", "--rig", "sim", "--protocol", "seed-bouc-wen", "--out", sim, "-q"])[0] == 0
    a, b = read_runs(ni), read_runs(sim)
    assert [r.name for r in a] == [r.name for r in b] and len(a) == 9
    for ra, rb in zip(a, b):
        assert ra.state == "completed" and len(ra) == len(rb)
        assert ra.attrs["role"] == rb.attrs["role"]
        assert ra.nominal_pressure == pytest.approx(rb.nominal_pressure)
        np.testing.assert_allclose(np.diff(ra.time), 1 / 500, rtol=0, atol=1e-12)
    with h5py.File(ni) as f, h5py.File(sim) as g:
        for name in f["runs"]:
            assert set(f["runs"][name]) == set(g["runs"][name])
