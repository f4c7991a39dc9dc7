"""Real drivers against the wire-level emulators over real sockets and ptys, with faults."""

from __future__ import annotations

import copy
import time

import pytest
from pty_support import needs_pty
from timing_records import too_busy_refusal

from pmalab.errors import ConfigError, RigError
from pmalab.paths import RIGS_DIR
from pmalab.rig.drivers.rigfile import build_modbus_rig, read_modbus_rig_file
from pmalab.rig.emulators.launcher import start_emulators


@pytest.fixture(scope="module")
def t7():
    """LabJack T7 emulator on a free TCP port, with a connected rig (no rate probe)."""
    with start_emulators(RIGS_DIR / "labjack-t7.toml", tcp_port=0, make_links=False) as emus:
        spec = emus.rig_spec()
        spec.probe_samples = 0
        rig = build_modbus_rig(spec)
        yield emus, rig
        rig.close()


def fresh_counts(rig):
    st = rig.sampler.link.stats
    return copy.copy(st)


def test_tcp_rig_reads_physics_and_commands_regulators(t7):
    emus, rig = t7
    rig.muscle_supply.request(0.4)
    rig.cylinder_regulator.set_pressure(0.3)
    time.sleep(0.8)
    b = rig.sampler.read_block()
    # the regulators really moved the simulated rig (ITV lag ~ tens of ms; muscle slower)
    assert b.cylinder_pressure[0] == pytest.approx(0.3, abs=0.01)
    assert 0.3 < b.muscle_pressure[0] < 0.42
    assert 50 < b.force[0] < 1500 and -5 < b.position[0] < 35
    assert emus.plant.physics.cylinder_command == pytest.approx(0.3, abs=1e-4)
    # the timestamp is the rig clock at the request
    t = rig.clock.now()
    assert t - 0.1 < b.time[0] <= t
    rig.cylinder_regulator.vent()
    assert emus.plant.physics.cylinder_command == 0.0


@pytest.mark.parametrize(
    ("fault", "counter"),
    [
        ("drop", "timeouts"),
        ("garble", "bad_frames"),
        ("exception", "exception_replies"),
        ("disconnect", "disconnects"),
        ("out_of_range", "out_of_range"),
    ],
)
def test_tcp_single_fault_is_retried_and_counted(t7, fault, counter):
    emus, rig = t7
    before = fresh_counts(rig)
    emus.faults.arm(fault, 1)
    v = rig.sampler.read_values()
    after = rig.sampler.link.stats
    assert emus.faults.injected[fault] >= 1 and emus.faults.pending() == 0
    assert getattr(after, counter) - getattr(before, counter) == 1
    assert after.retries - before.retries == 1
    assert after.failures == before.failures
    # a plausible reading of the (vented) cylinder gauge, not a garbled frame's value: its
    # noise around zero may read a kPa or so below it (the emulator runs on the real clock)
    assert -0.01 <= v["cylinder_pressure"] < 0.95
    if fault in ("drop", "garble", "disconnect"):
        assert after.reconnects - before.reconnects == 1  # fresh TCP stream


def test_tcp_faults_past_the_bound_raise_then_recover(t7):
    emus, rig = t7
    emus.faults.arm("drop", 10)
    t0 = time.perf_counter()
    with pytest.raises(RigError, match=r"after 4 attempts \(last: .*no reply; link so far: .*\d+ timeouts"):
        rig.sampler.read_values()
    # bounded: 4 attempts × 50 ms timeout, not forever
    assert time.perf_counter() - t0 < 1.5
    emus.faults.clear()
    assert rig.sampler.read_values()["muscle_pressure"] > -0.05  # link recovers by itself


def test_wrong_register_map_and_wrong_port_are_one_line_before_anything_moves(t7):
    emus, _ = t7
    spec = emus.rig_spec()
    spec.probe_samples = 0
    bad = copy.deepcopy(spec)
    ch = bad.channels[0]
    bad.channels[0] = type(ch)(ch.name, 40, ch.codec, ch.calibration, ch.raw_range)
    with pytest.raises(ConfigError, match=r"registers 0–41 rejected .*ILLEGAL DATA ADDRESS.*wrong register map") as ei:
        build_modbus_rig(bad)
    assert "\n" not in str(ei.value)
    bad = copy.deepcopy(spec)
    bad.outputs["cylinder_regulator"].address = 2000
    with pytest.raises(ConfigError, match=r"cylinder_regulator\] address 2000 rejected"):
        build_modbus_rig(bad)
    bad = copy.deepcopy(spec)
    bad.transport.port = spec.transport.port + 1 if spec.transport.port < 65535 else 1
    with pytest.raises(RigError, match=r"cannot connect .*refused"):
        build_modbus_rig(bad)


def test_missing_serial_port_is_one_line():
    spec = read_modbus_rig_file(RIGS_DIR / "generic-modbus-rtu.toml")
    spec.transport.port = "/dev/pmalab-no-such-port"
    with pytest.raises(RigError, match=r"no-such-port.*cannot connect"):
        build_modbus_rig(spec)


@needs_pty
def test_rtu_on_pty_faults_crc_drop_exception():
    with start_emulators(
        RIGS_DIR / "generic-modbus-rtu.toml", make_links=False, baud_pacing=False
    ) as emus:
        spec = emus.rig_spec()
        spec.probe_samples = 0
        # the emulator answers from this process's threads: on a busy machine they may
        # wait longer for a CPU than a real device takes to answer (the rig file's 0.1 s),
        # which would add a timeout to the counts of the faults injected
        spec.transport.timeout_s = 0.5
        rig = build_modbus_rig(spec)
        try:
            st = rig.sampler.link.stats
            for fault in ("garble", "drop", "exception"):
                emus.faults.arm(fault, 1)
                rig.sampler.read_values()
            assert (st.bad_frames, st.timeouts, st.exception_replies, st.failures) == (1, 1, 1, 0)
            rig.cylinder_regulator.set_pressure(0.45)
            time.sleep(0.3)
            assert rig.sampler.read_values()["cylinder_pressure"] == pytest.approx(0.45, abs=0.01)
        finally:
            rig.close()


@needs_pty
def test_rtu_at_115200_baud_cannot_do_500hz_refused_or_reduced():
    with start_emulators(RIGS_DIR / "generic-modbus-rtu.toml", make_links=False) as emus:
        spec = emus.rig_spec()
        spec.probe_samples = 60
        # the emulator answers from this process's threads: on a busy machine they may
        # wait longer for a CPU than a real device takes to answer (the rig file's 0.1 s)
        spec.transport.timeout_s = 1.0
        spec.allow_reduced_rate = False
        # refused as the slow link it is, busy machine or not: even its fastest read (a
        # 4-register read and a regulator write, ~7 ms on the wire) exceeds 500 Hz's budget
        with pytest.raises(RigError, match=r"sustainable about \d+ Hz < 500 Hz .*allow_reduced_rate"):
            build_modbus_rig(spec)
        spec.allow_reduced_rate = True
        try:
            rig = build_modbus_rig(spec)
        except RigError as exc:
            # on a machine so busy that the median read falls below the lowest fallback
            # rate, the probe says so on its own figures instead of blaming the link
            msg = too_busy_refusal(exc)
            assert float(msg.split("the fastest took ")[1].split(" ms")[0]) > 2.0, msg
            return
        try:
            timing = rig.info["timing"]
            # a 4-register RTU read needs > 2 ms on the wire at 115200 baud
            assert timing["p50_ms"] > 2.0 and timing["min_ms"] > 2.0
            assert timing["reduced"] and rig.sampler.sample_rate_Hz < 500
            assert rig.sampler.sample_rate_Hz <= timing["sustainable_Hz"]
        finally:
            rig.close()


@needs_pty
def test_itv_and_indicator_on_ptys_with_faults():
    with start_emulators(RIGS_DIR / "itv-serial.toml", tcp_port=0, make_links=False) as emus:
        spec = emus.rig_spec()
        spec.probe_samples = 0
        # the ITV emulator answers from this process's threads: on a busy machine they may
        # wait longer for a CPU than a real ITV takes to answer (the rig file's 0.2 s),
        # which would add a timeout to the counts of the faults injected
        for o in spec.outputs.values():
            if o.type == "itv-serial":
                o.timeout_s = 1.0
        rig = build_modbus_rig(spec)
        try:
            itv = rig.cylinder_regulator
            itv_emu = emus.itvs["cylinder_regulator"]
            ind_emu = emus.indicator
            rig.muscle_supply.request(0.3)
            itv.set_pressure(0.45)
            itv.flush()
            assert itv_emu.setpoint_counts == 512
            time.sleep(0.4)
            assert itv.monitor_pressure() == pytest.approx(0.45, abs=0.01)
            # the indicator's force follows the plant (zero-order hold of ~50 lines/s)
            v = rig.sampler.read_values()
            truth_force = emus.plant.sample()["force"]
            assert v["force"] == pytest.approx(truth_force, abs=15.0)
            # ITV faults: an UNKNOWN COMMAND reply and a dropped reply, both retried
            itv_emu.faults.arm("exception", 1)
            itv_emu.faults.arm("drop", 1)
            assert itv.monitor_pressure() == pytest.approx(0.45, abs=0.01)
            assert itv.stats.exception_replies == 1 and itv.stats.timeouts == 1
            # indicator: a garbled line is skipped and counted
            ind_emu.faults.arm("garble", 1)
            time.sleep(0.1)
            assert rig.sampler.stats()["indicator"]["bad_frames"] == 1
            # overload is a safety event
            ind_emu.faults.arm("out_of_range", 1)
            time.sleep(0.05)
            with pytest.raises(RigError, match="OVERLOAD"):
                for _ in range(50):
                    rig.sampler.read_values()
                    time.sleep(0.002)
            # a silent indicator (cable pulled) is a device fault after stale_after_s
            ind_emu.silence_s = 1.0
            ind_emu.faults.arm("disconnect", 1)
            time.sleep(0.1)
            with pytest.raises(RigError, match=r"no weight line for more than 0\.5 s"):
                for _ in range(200):
                    rig.sampler.read_values()
                    time.sleep(0.005)
        finally:
            rig.close()
        assert itv_emu.setpoint_counts == 0  # closing vented the ITV


def test_device_watchdog_vents_when_the_host_goes_silent():
    with start_emulators(RIGS_DIR / "labjack-t7.toml", tcp_port=0, make_links=False) as emus:
        assert emus.modbus.watchdog_s == 1.0  # from [rig.emulator] watchdog_s
        spec = emus.rig_spec()
        spec.probe_samples = 0
        rig = build_modbus_rig(spec)
        try:
            rig.cylinder_regulator.set_pressure(0.5)
            assert emus.plant.physics.cylinder_command == pytest.approx(0.5, abs=1e-4)
            time.sleep(0.6)  # still within the watchdog time: nothing happens
            assert emus.modbus.model.watchdog_trips == 0
            time.sleep(0.8)  # host silent > 1 s (crashed, cable pulled): the device vents
            assert emus.modbus.model.watchdog_trips == 1
            assert emus.plant.physics.cylinder_command == 0.0
            regs = rig.sampler.link.read_registers(1000, 2)
            assert rig.cylinder_regulator.codec.decode(regs) == 0.0  # DAC0 reads back 0 V
        finally:
            rig.close()


def test_generic_int16_module_with_polynomial_lvdt_and_tare():
    with start_emulators(RIGS_DIR / "generic-modbus.toml", tcp_port=0, make_links=False) as emus:
        spec = emus.rig_spec()
        spec.probe_samples = 0
        rig = build_modbus_rig(spec)
        try:
            assert rig.info["input_block"] == {"address": 0, "count": 4, "function": 4}
            # at rest the load cell carries no tension: tare on it
            tare = rig.sampler.tare("force", n=20)
            assert abs(tare) < 5.0
            assert abs(rig.sampler.read_values()["force"]) < 5.0
            rig.muscle_supply.request(0.3)
            rig.cylinder_regulator.set_pressure(0.2)
            time.sleep(0.8)
            # the plant still moves (~5 mm/s at 0.8 s): the device's reading is compared
            # with the plant sampled just before and just after it (on an idle machine a
            # millisecond apart; on a busy one the read may take tens of ms, and the reading
            # lies between the two)
            before = emus.plant.sample()
            v = rig.sampler.read_values()
            s = emus.plant.sample()
            # 10 V / 32000 counts: 0.08 N, 0.3 µm, 0.08 kPa per count; sensor noise dominates
            for ch, tol, zero in (("position", 0.05, 0.0), ("force", 3.0, tare)):
                lo, hi = sorted((before[ch] - zero, s[ch] - zero))
                assert lo - tol <= v[ch] <= hi + tol, (ch, before[ch] - zero, v[ch], s[ch] - zero)
            assert v["cylinder_pressure"] == pytest.approx(0.2, abs=0.005)
            # the uint16 analog output: 0.2 MPa on 0–10 V = 2.222 V = 7111 counts
            regs = rig.sampler.link.read_registers(100, 1)
            assert regs == [round(0.2 / 0.9 * 10 / 0.0003125)]
        finally:
            rig.close()
