"""Drivers against recorded request/reply bytes (PyMeasure ``expected_protocol`` style)."""

from __future__ import annotations

import struct

import pytest

from pmalab.errors import RigError
from pmalab.rig.base import RealClock, VentOutcome
from pmalab.rig.drivers.calibration import Calibration, RegisterCodec
from pmalab.rig.drivers.itv_serial import ItvSerialRegulator
from pmalab.rig.drivers.loadcell_serial import G0, LoadCellIndicator, parse_line
from pmalab.rig.drivers.modbus_daq import AnalogChannel, ModbusAnalogOutput, ModbusSampler
from pmalab.rig.drivers.modbus_link import FC_READ_INPUT, ModbusLink
from pmalab.rig.drivers.testing import CLOSE, ProtocolAdapter, expected_protocol


def crc16(frame: bytes) -> bytes:
    """Modbus CRC-16 (poly 0xA001, init 0xFFFF), low byte first — written independently."""
    crc = 0xFFFF
    for b in frame:
        crc ^= b
        for _ in range(8):
            crc = (crc >> 1) ^ 0xA001 if crc & 1 else crc >> 1
    return struct.pack("<H", crc)


def f32(*values: float) -> bytes:
    return b"".join(struct.pack(">f", v) for v in values)


def mbap(tid: int, pdu: bytes, unit: int = 1) -> bytes:
    return struct.pack(">HHHB", tid, 0, len(pdu) + 1, unit) + pdu


def t7_sampler(adapter: ProtocolAdapter) -> ModbusSampler:
    link = ModbusLink(adapter, "tcp", device_id=1, timeout=0.01, retries=2)
    p = Calibration.two_point(1.0, 0.0, 5.0, 1.0)
    chans = [
        AnalogChannel("muscle_pressure", 0, RegisterCodec(), p, (0.8, 5.2)),
        AnalogChannel("cylinder_pressure", 2, RegisterCodec(), p, (0.8, 5.2)),
        AnalogChannel("position", 4, RegisterCodec(), Calibration.two_point(0, -10, 10, 40), (-0.2, 10.2)),
        AnalogChannel("force", 6, RegisterCodec(), Calibration((0.0, 250.0), tare=5.0), (-0.5, 10.2)),
    ]
    return ModbusSampler(link, chans, RealClock())


def t7_reply(tid: int, volts=(3.0, 2.0, 4.0, 4.0)) -> bytes:
    return mbap(tid, bytes([3, 16]) + f32(*volts))


def test_tcp_block_read_is_one_request_with_exact_bytes():
    pairs = [(bytes.fromhex("0001 0000 0006 01 03 0000 0008"), t7_reply(1))]
    with expected_protocol(t7_sampler, pairs) as s:
        b = s.read_block()
    assert len(b) == 1
    assert b.muscle_pressure[0] == pytest.approx(0.5)
    assert b.cylinder_pressure[0] == pytest.approx(0.25)
    assert b.position[0] == pytest.approx(10.0)
    assert b.force[0] == pytest.approx(4.0 * 250.0 - 5.0)  # tare subtracted
    assert s.link.stats.requests == 1 and s.link.stats.retries == 0


def test_tcp_timeout_then_reconnect_and_retry_counted():
    pairs = [
        (bytes.fromhex("0001 0000 0006 01 03 0000 0008"), None),  # dropped reply
        (bytes.fromhex("0002 0000 0006 01 03 0000 0008"), t7_reply(2)),
    ]
    with expected_protocol(t7_sampler, pairs) as s:
        v = s.read_values()
        assert s.link.adapter.opens == 2  # reconnected after the timeout
    assert v["muscle_pressure"] == pytest.approx(0.5)
    st = s.link.stats
    assert (st.timeouts, st.retries, st.reconnects, st.failures) == (1, 1, 1, 0)


def test_tcp_exception_reply_and_garbled_header_then_success():
    pairs = [
        (bytes.fromhex("0001 0000 0006 01 03 0000 0008"), mbap(1, bytes([0x83, 0x06]))),  # busy
        (bytes.fromhex("0002 0000 0006 01 03 0000 0008"), b"\x00\x03\xff\xff\x00\x13\x01" + b"\x00" * 18),
        (bytes.fromhex("0003 0000 0006 01 03 0000 0008"), t7_reply(3)),
    ]
    with expected_protocol(t7_sampler, pairs) as s:
        s.read_values()
    st = s.link.stats
    assert (st.exception_replies, st.bad_frames, st.retries) == (1, 1, 2)


def test_tcp_stale_reply_is_skipped():
    # the reply to an earlier request arrives before the current one: skipped, not used
    pairs = [(bytes.fromhex("0001 0000 0006 01 03 0000 0008"), t7_reply(7, (1.0, 1.0, 0.0, 0.0)) + t7_reply(1))]
    with expected_protocol(t7_sampler, pairs) as s:
        v = s.read_values()
    assert v["muscle_pressure"] == pytest.approx(0.5)
    assert s.link.stats.stale_replies == 1


def test_out_of_range_raw_value_retried_then_refused():
    bad = (3.0, 2.0, 4.0, 11.5)  # load-cell amplifier saturated beyond 10.2 V
    pairs = [(bytes.fromhex(f"{i:04x} 0000 0006 01 03 0000 0008"), t7_reply(i, bad)) for i in (1, 2, 3)]
    with expected_protocol(t7_sampler, pairs) as s, pytest.raises(RigError, match=r"force raw value 11\.5"):
        s.read_values()
    assert s.link.stats.out_of_range == 3 and s.link.stats.failures == 1


def test_disconnect_counted_and_bounded():
    pairs = [(CLOSE, None)] * 3
    with expected_protocol(t7_sampler, pairs) as s, pytest.raises(RigError, match="after 3 attempts"):
        s.read_values()
    assert s.link.stats.disconnects == 3


def test_rtu_read_input_int16_with_crc_and_bad_crc_retry():
    req = bytes.fromhex("01 04 0000 0004")
    req += crc16(req)
    counts = [16000, 8000, 9600, 3200]  # 5 V, 2.5 V, 3 V, 1 V at 10 V / 32000 counts
    body = bytes([1, 4, 8]) + struct.pack(">4h", *counts)
    good = body + crc16(body)
    garbled = good[:-1] + bytes([good[-1] ^ 0xFF])

    def make(adapter: ProtocolAdapter) -> ModbusSampler:
        link = ModbusLink(adapter, "rtu", device_id=1, timeout=0.01, retries=2)
        codec = RegisterCodec("int16", scale=10 / 32000)
        p = Calibration.two_point(1.0, 0.0, 5.0, 1.0)
        chans = [
            AnalogChannel("position", 0, codec, Calibration((-10.0, 5.1, -0.01))),
            AnalogChannel("force", 1, codec, Calibration.two_point(0, 0, 10, 2500)),
            AnalogChannel("muscle_pressure", 2, codec, p),
            AnalogChannel("cylinder_pressure", 3, codec, p),
        ]
        return ModbusSampler(link, chans, RealClock(), function=FC_READ_INPUT)

    with expected_protocol(make, [(req, garbled), (req, good)]) as s:
        v = s.read_values()
    assert v["position"] == pytest.approx(-10 + 5.1 * 5 - 0.01 * 25)
    assert v["force"] == pytest.approx(625.0)
    assert v["muscle_pressure"] == pytest.approx(0.5)
    assert v["cylinder_pressure"] == pytest.approx(0.0)
    assert s.link.stats.bad_frames == 1


def _dac(adapter):
    link = ModbusLink(adapter, "tcp", timeout=0.01, retries=0)
    return ModbusAnalogOutput(link, 1000, RegisterCodec(), Calibration.two_point(0, 0, 5, 0.9), (0.0, 5.0))


def test_analog_output_writes_float32_dac_and_a_vent_without_reply_is_failed():
    # 0.45 MPa on a 0–5 V ITV1051 = 2.5 V = 0x40200000 to DAC0 (address 1000 = 0x03e8)
    req = bytes.fromhex("0001 0000 000b 01 10 03e8 0002 04 4020 0000")
    echo = mbap(1, bytes.fromhex("10 03e8 0002"))
    vent_req = bytes.fromhex("0002 0000 000b 01 10 03e8 0002 04 0000 0000")
    with expected_protocol(_dac, [(req, echo), (vent_req, None)]) as out:
        out.set_pressure(0.45)
        res = out.vent()  # no reply: must not raise, and must not claim a vent
        assert res.outcome is VentOutcome.FAILED
        assert "not acknowledged after 1 attempts" in res.detail and "no reply" in res.detail
        with pytest.raises(RigError, match="outside"):
            out.set_pressure(0.95)


def test_analog_output_vent_is_confirmed_by_ack_and_read_back():
    vent_req = bytes.fromhex("0001 0000 000b 01 10 03e8 0002 04 0000 0000")
    echo = mbap(1, bytes.fromhex("10 03e8 0002"))
    read_req = bytes.fromhex("0002 0000 0006 01 03 03e8 0002")
    zero = mbap(2, bytes.fromhex("03 04 0000 0000"))
    with expected_protocol(_dac, [(vent_req, echo), (read_req, zero)]) as out:
        res = out.vent()
    assert res.ok and "register 1000 reads back 0" in res.detail
    # acknowledged, but something else holds the DAC at 2.5 V: not confirmed
    still = mbap(2, bytes.fromhex("03 04 4020 0000"))
    with expected_protocol(_dac, [(vent_req, echo), (read_req, still)]) as out:
        res = out.vent()
    assert res.outcome is VentOutcome.FAILED and "reads back 2.5 instead of 0" in res.detail
    # a device that refuses to read outputs back (exception 02): the acknowledgement counts
    refused = mbap(2, bytes.fromhex("83 02"))
    with expected_protocol(_dac, [(vent_req, echo), (read_req, refused)]) as out:
        res = out.vent()
    assert res.ok and "does not read outputs back" in res.detail


def test_itv_serial_set_mon_and_error_reply():
    pairs = [
        (b"MON\r\n", b"MON 0\r\n"),
        (b"SET 512\r\n", b"UNKNOWN COMMAND\r\n"),  # line noise hit the command: retried
        (b"SET 512\r\n", b"OK\r\n"),
        (b"MON\r\n", b"MON 511\r\n"),
        (b"SET 0\r\n", b"OK\r\n"),
        (b"MON\r\n", b"MON 511\r\n"),
    ]
    with expected_protocol(lambda a: ItvSerialRegulator(a, 0.9, timeout=0.01), pairs) as itv:
        assert itv.monitor_pressure() == 0.0
        itv.set_pressure(0.45)  # 0.45/0.9*1023 = 511.5 -> 512
        itv.flush()
        assert itv.monitor_pressure() == pytest.approx(511 / 1023 * 0.9)
        itv.vent_confirm_s = 0.0
        res = itv.vent()  # SET 0 acknowledged, but MON still reads the old pressure
    assert itv.stats.exception_replies == 1
    assert res.outcome is VentOutcome.FAILED
    assert "SET 0 acknowledged" in res.detail and "still reads 0.450 MPa" in res.detail


def test_itv_vent_confirmed_once_mon_falls_and_failed_without_ok():
    pairs = [(b"SET 0\r\n", b"OK\r\n"), (b"MON\r\n", b"MON 300\r\n"), (b"MON\r\n", b"MON 10\r\n")]
    with expected_protocol(lambda a: ItvSerialRegulator(a, 0.9, timeout=0.01), pairs) as itv:
        res = itv.vent()
    assert res.ok and "output reads 0.009 MPa" in res.detail
    pairs = [(b"SET 0\r\n", None)] * 3  # the regulator does not answer
    with expected_protocol(lambda a: ItvSerialRegulator(a, 0.9, timeout=0.01, retries=2), pairs) as itv:
        res = itv.vent()
    assert res.outcome is VentOutcome.FAILED and "SET 0 not acknowledged" in res.detail


def test_itv_serial_gives_up_after_bound():
    pairs = [(b"SET 1023\r\n", b"UNKNOWN COMMAND\r\n")] * 3
    with expected_protocol(lambda a: ItvSerialRegulator(a, 0.9, timeout=0.01, retries=2), pairs) as itv:
        with pytest.raises(RigError, match="UNKNOWN COMMAND"):
            itv.set_counts(1023)


def test_indicator_line_parsing():
    r = parse_line(b"ST,GS,+0012.34kg\r\n")
    assert r.force_N == pytest.approx(12.34 * G0) and r.stable and not r.overload
    r = parse_line(b"US,NT,-0001.50N\r\n")
    assert r.force_N == pytest.approx(-1.5) and not r.stable and r.net
    assert parse_line(b"OL,GS,+9999.99kg\r\n").overload
    for bad in (b"ST,GS,+12.3xg\r\n", b"XX,GS,+1.0kg\r\n", b"\x00\xffST\r\n"):
        with pytest.raises((ValueError, UnicodeDecodeError)):
            parse_line(bad)


def test_indicator_stream_skips_garbage_and_flags_overload():
    stream = [(None, b"ST,GS,+0010.00kg\r\nST,G#,+00?\r\nUS,GS,+0020.00kg\r\n")]
    ind = LoadCellIndicator(ProtocolAdapter(stream), stale_after_s=1.0)
    ind.connect(wait_s=1.0)
    import time

    deadline = time.perf_counter() + 1.0
    while ind.lines < 2 and time.perf_counter() < deadline:
        time.sleep(0.005)
    assert ind.force() == pytest.approx(20.0 * G0)
    assert ind.stats.bad_frames == 1
    ind.close()
    ol = LoadCellIndicator(ProtocolAdapter([(None, b"OL,GS,+9999.99kg\r\n")]))
    ol.connect()
    with pytest.raises(RigError, match="OVERLOAD"):
        ol.force()
    ol.close()
