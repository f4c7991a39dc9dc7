"""The link probe tells a busy computer from a slow link.

The probe times block reads on the host's clock; a read also waits whenever the driver (or
an emulator in the same process) waits for a CPU.  Scripted here: each read takes a given
time on a fake clock and the process waits for a CPU a given share of it (the kernel's
count, :func:`pmalab.rig.drivers.modbus_daq.cpu_wait_s`, replaced).
"""

from __future__ import annotations

import itertools
import math
import sys
from types import SimpleNamespace

import pytest

from pmalab.acquisition.runner import recording_rate
from pmalab.errors import RigError
from pmalab.rig.base import RealClock
from pmalab.rig.drivers import modbus_daq
from pmalab.rig.drivers.calibration import Calibration, RegisterCodec
from pmalab.rig.drivers.modbus_daq import (
    HOST_BUSY_SHARE,
    AnalogChannel,
    ModbusSampler,
    cpu_wait_s,
)
from pmalab.rig.drivers.modbus_link import ModbusLink
from pmalab.rig.drivers.testing import ProtocolAdapter


class FakeTime:
    """``time`` for the probe: a clock that moves only when a scripted read takes time."""

    def __init__(self) -> None:
        self.t = 0.0

    def perf_counter(self) -> float:
        return self.t


def scripted_sampler(monkeypatch, reads_ms: list[float], wait_share: float | list[float],
                     allow_reduced: bool) -> ModbusSampler:
    """A sampler whose reads take ``reads_ms`` in turn, the process waiting for a CPU
    ``wait_share`` of every read (a number), or of each read in turn (a list)."""
    clock = FakeTime()
    waited = [0.0]
    monkeypatch.setattr(modbus_daq, "time", clock)
    monkeypatch.setattr(modbus_daq, "cpu_wait_s", lambda: waited[0])
    link = ModbusLink(ProtocolAdapter([]), "tcp", device_id=1, timeout=0.01, retries=0)
    p = Calibration.two_point(1.0, 0.0, 5.0, 1.0)
    chans = [AnalogChannel(c, i, RegisterCodec(), p) for i, c in
             enumerate(("position", "force", "muscle_pressure", "cylinder_pressure"))]
    s = ModbusSampler(link, chans, RealClock(), allow_reduced_rate=allow_reduced)
    shares = wait_share if isinstance(wait_share, list) else [wait_share] * len(reads_ms)
    script = itertools.cycle(zip(reads_ms, shares, strict=True))

    def read_values() -> dict[str, float]:
        ms, share = next(script)
        clock.t += ms * 1e-3
        waited[0] += share * ms * 1e-3
        return {}

    s.read_values = read_values  # type: ignore[method-assign]
    return s


#: a fast link on a busy computer: one read in ten gets a CPU at once (0.3 ms), the rest
#: wait for one (4.5 ms): the median says 111 Hz, the link does 500 Hz
FAST_LINK_BUSY = [0.3] + [4.5] * 9
#: ... and the waits that make it so: none in the fast read, 4.2 ms of each slow one
FAST_LINK_WAITS = [0.0] + [4.2 / 4.5] * 9
#: a link too slow for 500 Hz however idle the computer: no read under 4 ms (median 5.5)
SLOW_LINK = [4.0, 5.5, 5.5, 6.0]


def test_a_fast_link_on_a_busy_computer_is_not_blamed(monkeypatch):
    s = scripted_sampler(monkeypatch, FAST_LINK_BUSY, FAST_LINK_WAITS, allow_reduced=False)
    with pytest.raises(RigError) as ei:
        s.check_rate(500.0, 100)
    msg = str(ei.value)
    assert "too busy to judge the link" in msg
    assert "threads, summed, waited for a CPU 93 % of the time" in msg  # may pass 100 %
    assert "median" in msg and "the fastest took 0.30 ms" in msg
    assert "faster link" not in msg and "\n" not in msg
    assert s.last_probe is not None and s.last_probe.host_busy
    assert s.last_probe.cpu_wait_share == pytest.approx(37.8 / 40.8)


def test_a_slow_link_is_blamed_when_the_cpu_waits_cannot_explain_its_reads(monkeypatch):
    # the same reads (one fast, the rest 4.5 ms: a link that answers at once only now and
    # then), on a computer busy enough to cross the threshold, but the process waited only
    # 1.2 ms of each slow read: with every wait taken out the reads still average 3 ms, far
    # over 500 Hz's 1 ms budget.  The link is too slow, and is named as such
    waits = [0.0] + [1.2 / 4.5] * 9
    s = scripted_sampler(monkeypatch, FAST_LINK_BUSY, waits, allow_reduced=False)
    with pytest.raises(RigError, match=r"block reads take 4\.50 ms .*sustainable about 111 Hz "
                       r"< 500 Hz requested; use a faster link"):
        s.check_rate(500.0, 100)
    assert s.last_probe is not None and s.last_probe.host_busy
    assert s.last_probe.min_ms == pytest.approx(0.3)
    # reduced rates allowed, below the lowest fallback: reads of 90 ms that waited 30 ms
    # each are over 10 Hz's 50 ms budget without the waits too
    s = scripted_sampler(monkeypatch, [3.0] + [90.0] * 9, [0.0] + [1 / 3] * 9, True)
    with pytest.raises(RigError, match=r"sustainable rate 11\.1 Hz is too low|too low to record"):
        s.check_rate(500.0, 100)
    assert s.last_probe is not None and s.last_probe.host_busy


def test_the_same_reads_on_an_idle_computer_blame_the_link(monkeypatch):
    s = scripted_sampler(monkeypatch, FAST_LINK_BUSY, 0.01, allow_reduced=False)
    with pytest.raises(RigError, match=r"sustainable about 111 Hz < 500 Hz requested; use a "
                       r"faster link or set allow_reduced_rate"):
        s.check_rate(500.0, 100)
    assert s.last_probe is not None and not s.last_probe.host_busy


@pytest.mark.parametrize("wait_share", [0.01, 0.9])
def test_a_slow_link_is_refused_as_slow_on_a_busy_computer_too(monkeypatch, wait_share):
    s = scripted_sampler(monkeypatch, SLOW_LINK, wait_share, allow_reduced=False)
    with pytest.raises(RigError, match=r"block reads take 5\.50 ms .*sustainable about 91 Hz "
                       r"< 500 Hz requested; use a faster link"):
        s.check_rate(500.0, 100)
    assert s.last_probe is not None and s.last_probe.min_ms == pytest.approx(4.0)


def test_reduced_rate_below_every_fallback_says_which(monkeypatch):
    # reads of ~90 ms: 5.6 Hz, under the lowest fallback (10 Hz); on a busy computer whose
    # fastest read took 3 ms that is the computer's doing, on an idle one the link's
    reads = [3.0] + [90.0] * 9
    s = scripted_sampler(monkeypatch, reads, 0.8, allow_reduced=True)
    with pytest.raises(RigError, match=r"too busy to judge the link: .*CPU 80 % .*fastest "
                       r"took 3\.00 ms; close other programs"):
        s.check_rate(500.0, 100)
    s = scripted_sampler(monkeypatch, reads, 0.0, allow_reduced=True)
    with pytest.raises(RigError, match=r"sustainable rate 5\.6 Hz is too low to record"):
        s.check_rate(500.0, 100)


def test_a_reduced_rate_on_a_busy_computer_says_so(monkeypatch):
    s = scripted_sampler(monkeypatch, FAST_LINK_BUSY, 0.5, allow_reduced=True)
    res = s.check_rate(500.0, 100)
    assert s.sample_rate_Hz == 100.0 and res.host_busy

    timing = {**res.as_dict(), "host_busy": res.host_busy, "reduced": True}
    rig = SimpleNamespace(sampler=s, info={"name": "T7", "timing": timing})
    proto = SimpleNamespace(sample_rate_Hz=500.0, path=None, name="p", runs=[])
    rate, warning = recording_rate(rig, proto)  # type: ignore[arg-type]
    assert rate == 100.0 and warning is not None
    assert "on this busy computer, sustained about 111 Hz" in warning
    assert "threads, summed, waited for a CPU 50 % of the probe" in warning
    # an idle computer's probe: the link is named as the limit, as before
    timing["host_busy"] = False
    _, warning = recording_rate(rig, proto)  # type: ignore[arg-type]
    assert warning is not None and "(its link sustains about 111 Hz)" in warning


def test_cpu_wait_is_unknown_where_the_kernel_keeps_no_scheduler_statistics(tmp_path):
    # a kernel without them writes "0 0 0" for every thread: no count, not a wait of zero
    for tid, text in (("100", "0 0 0\n"), ("101", "0 0 0\n")):
        (tmp_path / tid).mkdir()
        (tmp_path / tid / "schedstat").write_text(text)
    assert cpu_wait_s(str(tmp_path)) is None
    (tmp_path / "101" / "schedstat").write_text("1500 2500000 7\n")
    assert cpu_wait_s(str(tmp_path)) == pytest.approx(2.5e-3)
    assert cpu_wait_s(str(tmp_path / "none")) is None


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="Linux scheduler statistics")
def test_cpu_wait_is_the_kernels_count_for_this_process():
    a = cpu_wait_s()
    x = sum(i * i for i in range(200_000))  # some work between the two reads
    b = cpu_wait_s()
    assert x > 0 and a is not None and b is not None
    assert math.isfinite(a) and 0.0 <= a <= b
    assert HOST_BUSY_SHARE < 1.0
