"""Live view without a browser: address parsing, the never-blocking feed and its drop
count, the hub's replay for late browsers, the server's routes and stop rules, the runner
hook (an observer cannot break or alter a recording; a stop request is a safe abort), and
``pmalab view`` following a file while it grows."""

from __future__ import annotations

import http.client
import json
import os
import signal
import socket
import subprocess
import sys
import time

import numpy as np
import pytest
from test_acq_fakes import TWO_RUNS, make_fake_rig

from pmalab.acquisition.live import FileFollower, Hub, LiveServer, parse_address
from pmalab.acquisition.live.address import is_loopback
from pmalab.acquisition.live.feed import RingFeed, RingReader, ring_bytes
from pmalab.acquisition.live.hub import Cursor
from pmalab.acquisition.live.margins import Margins
from pmalab.acquisition.live.pump import Pump
from pmalab.acquisition.protocol import parse_protocol
from pmalab.acquisition.recorder import RECORDED, Recorder
from pmalab.acquisition.runner import RunnerOptions, RunObserver, run_protocol
from pmalab.errors import ConfigError, SafetyAbort
from pmalab.runfile import read_runs

LIMITS = {
    "max_force_N": 1000.0,
    "min_position_mm": -5.0,
    "max_position_mm": 35.0,
    "max_muscle_pressure_MPa": 0.6,
    "max_cylinder_pressure_MPa": 0.9,
}


# ------------------------------------------------------------------ address
@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ("8765", ("127.0.0.1", 8765)),
        ("0.0.0.0:80", ("0.0.0.0", 80)),
        ("localhost:0", ("localhost", 0)),
        ("[::1]:9000", ("::1", 9000)),
    ],
)
def test_parse_address(text, expected):
    assert parse_address(text) == expected


@pytest.mark.parametrize("text", ["abc", "70000", ":80", "::1:80", "host:-1"])
def test_parse_address_refuses_with_one_line(text):
    with pytest.raises(ConfigError) as ei:
        parse_address(text)
    assert str(ei.value).startswith("--live:") and "\n" not in str(ei.value)


def test_loopback_addresses():
    assert is_loopback("127.0.0.1") and is_loopback("::1") and is_loopback("::ffff:127.0.0.1")
    assert not is_loopback("192.168.1.5") and not is_loopback("0.0.0.0")


# ------------------------------------------------------------------ feed → pump → hub
class _Writer:
    """Stands in for RunWriter: records what reaches the file."""

    def __init__(self):
        self.rows = []
        self.n = self.n_late = self.n_missed = 0
        self.buffered = 0

    channels = RECORDED

    def append(self, row, lateness):
        self.rows.append((*row, lateness))

    def add(self, *row):
        self.append(row[:-1], row[-1])


def _spec(frequency=1.0):
    return parse_protocol(TWO_RUNS, "t.toml").runs[0]


def _ring(rows):
    buf = bytearray(ring_bytes(rows))
    events = []
    return buf, events, RingFeed(buf, 2, events.append, rows=rows), RingReader(buf, rows)


def test_tap_stores_every_sample_and_the_ring_drops_the_oldest_counted():
    proto = parse_protocol(TWO_RUNS, "t.toml")
    _, events, feed, reader = _ring(100)
    w = _Writer()
    feed.run_started(0, proto.runs[0], w)
    assert events == [("start", 0, events[0][2])] and events[0][2]["name"] == "first"
    for k in range(1000):
        w.late = k
        w.add(k / 500, 20.0, 300.0 + k, 0.4, 0.2, 0.25, 1e-5)
    assert len(w.rows) == 1000 and w.rows[-1][2] == 1299.0  # the file gets every sample
    hub = Hub({"mode": "live"})
    pump = Pump(reader, hub, [r.duration_s for r in proto.runs], 500.0, Margins.from_limits(LIMITS))
    pump.events.extend(events)
    pump.pump()
    assert reader.dropped == 900  # the reader came after 1000 samples into a 100-row ring
    (run,) = hub.runs.values()
    pts = json.loads(run.frames[0].decode().split("data: ", 1)[1])
    assert pts["t"] == [k / 500 for k in range(900, 1000, 10)]  # stride 10 on the seq grid
    status = pump.status()
    assert status["dropped"] == 900 and status["safety"]["state"] == "ok"
    assert status["samples"] == 1000
    force = next(m for m in status["margins"] if m["channel"] == "force")
    # only the rows still in the ring reach the margins (the last one: F = 1299 N, 299 N past)
    assert force["reading"] == 1299.0 and force["margin"] == pytest.approx(-299.0)
    assert force["lowest"] == pytest.approx(-299.0)
    for k in range(1000, 1050):  # drained again: only what is new, none dropped
        w.add(k / 500, 20.0, 300.0, 0.4, 0.2, 0.25, 1e-5)
    rows = reader.drain()
    assert rows[:, 0].tolist() == list(range(1000, 1050)) and reader.dropped == 900


def test_ring_rows_overwritten_while_being_read_are_not_trusted():
    _, _, feed, reader = _ring(8)
    w = _Writer()
    feed.run_started(0, parse_protocol(TWO_RUNS, "t.toml").runs[0], w)
    for k in range(8):
        w.add(k, 0, 0, 0, 0, 0, 0)
    real_head = reader._head

    # the writer laps the reader between its reading the head and copying the rows
    class Racing:
        def __init__(self):
            self.reads = 0

        def __getitem__(self, i):
            self.reads += 1
            if self.reads == 3:  # the re-read after the copy
                for k in range(8, 12):
                    w.add(k, 0, 0, 0, 0, 0, 0)
            return real_head[i]

    reader._head = Racing()
    rows = reader.drain()
    assert rows[:, 0].tolist() == [4, 5, 6, 7] and reader.dropped == 4


def test_margins_against_the_interlock_thresholds():
    m = Margins.from_limits(LIMITS)
    m.update(
        np.array([30.0, 34.0]),
        np.array([-900.0, 200.0]),
        np.array([0.4, 0.62]),
        np.array([0.1, 0.2]),
    )
    rows = {r["channel"]: r for r in m.rows()}
    assert rows["position"]["margin"] == pytest.approx(1.0)
    assert rows["force"]["lowest"] == pytest.approx(100.0)
    assert rows["muscle_pressure"]["margin"] == pytest.approx(0.63 - 0.62)  # 5 % over 0.6
    assert rows["muscle_pressure"]["used"] > 0.95


def test_hub_replays_the_current_run_to_a_late_browser_and_follows_new_runs():
    hub = Hub({"mode": "live"})
    hub.start_run(0, {"name": "a"})
    for k in range(5):
        hub.add_points(0, {"t": [k], "x": [1], "f": [2], "pm": [3], "pc": [4], "cmd": [5]})
    late = Cursor()
    text = hub.updates(late).decode()
    assert text.count("event: run") == 1 and text.count("event: points") == 5
    assert hub.updates(late) == b""  # nothing new
    pinned = Cursor(follow=False, run=0)
    hub.updates(pinned)
    hub.start_run(1, {"name": "b"})
    hub.add_points(1, {"t": [0], "x": [1], "f": [2], "pm": [3], "pc": [4], "cmd": [5]})
    assert '"name":"b"' in hub.updates(late).decode() and late.run == 1
    assert hub.updates(pinned) == b""  # a browser looking at run 0 stays there
    hub.finish("done")
    assert "event: end" in hub.updates(late).decode() and late.ended


# ------------------------------------------------------------------ server
def _events(port, path="/events", until="points", timeout=30.0):
    conn = http.client.HTTPConnection("127.0.0.1", port, timeout=timeout)
    conn.request("GET", path)
    resp = conn.getresponse()
    assert resp.status == 200 and resp.getheader("Content-Type") == "text/event-stream"
    text = ""
    deadline = time.monotonic() + timeout
    while f"event: {until}" not in text and time.monotonic() < deadline:
        text += resp.fp.readline().decode()
    assert f"event: {until}" in text, f"no '{until}' event within {timeout:g} s: {text[-300:]}"
    text += resp.fp.readline().decode()  # its data line
    conn.close()
    return text


def _post_stop(host, port, headers=None, source=None):
    conn = http.client.HTTPConnection(host, port, timeout=5, source_address=source)
    conn.request("POST", "/stop", headers=headers or {})
    resp = conn.getresponse()
    body = json.loads(resp.read())
    conn.close()
    return resp.status, body


@pytest.fixture
def live_server():
    hub = Hub({"mode": "live", "file": "x.h5"})
    hub.start_run(0, {"name": "a", "n_runs": 1})
    hub.add_points(
        0, {"t": [0.0], "x": [20.0], "f": [300.0], "pm": [0.4], "pc": [0.1], "cmd": [0.1]}
    )
    stops = []
    server = LiveServer(hub, "127.0.0.1", 0, on_stop=lambda: stops.append(1) or "stopping")
    server.start()
    yield server, hub, stops
    hub.finish("test over")
    server.close(grace_s=0.5)


def test_server_serves_the_page_its_assets_and_the_stream(live_server):
    server, _, _ = live_server
    conn = http.client.HTTPConnection("127.0.0.1", server.port, timeout=5)
    for path, status, needle in [
        ("/", 200, b"/assets/uPlot.iife.min.js"),
        ("/assets/uPlot.iife.min.js", 200, b"uPlot"),
        ("/assets/uPlot.LICENSE.txt", 200, b"MIT"),
        ("/assets/../server.py", 404, b""),
        ("/assets/hub.py", 404, b""),
    ]:
        conn.request("GET", path)
        resp = conn.getresponse()
        body = resp.read()
        assert resp.status == status and needle in body, path
    conn.close()
    text = _events(server.port)
    hello = json.loads(text.split("event: hello\ndata: ", 1)[1].split("\n", 1)[0])
    assert hello["mode"] == "live" and hello["stop_allowed"] is True
    assert '"f":[300.0]' in text


def test_stop_needs_the_pages_header_and_is_acted_on_once_asked(live_server):
    server, _, stops = live_server
    code, body = _post_stop("127.0.0.1", server.port)
    assert code == 403 and not stops
    code, body = _post_stop("127.0.0.1", server.port, {"X-Pmalab-Stop": "1"})
    assert code == 202 and body["ok"] and stops == [1]


def test_stop_on_a_file_view_is_refused():
    hub = Hub({"mode": "view"})
    server = LiveServer(hub, "127.0.0.1", 0, on_stop=None)
    server.start()
    try:
        code, body = _post_stop("127.0.0.1", server.port, {"X-Pmalab-Stop": "1"})
        assert code == 409 and "nothing to stop" in body["message"]
    finally:
        server.close(grace_s=0)


def _outward_ip():
    """This machine's address on a non-loopback interface (None when it has none)."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        try:
            s.connect(("192.0.2.1", 9))  # TEST-NET: no packet is sent for UDP connect
            ip = s.getsockname()[0]
        except OSError:
            return None
    return None if is_loopback(ip) or ip == "0.0.0.0" else ip


def test_stop_from_another_address_is_forbidden():
    ip = _outward_ip()
    if ip is None:
        pytest.skip("no non-loopback interface to send a request from")
    stops = []
    hub = Hub({"mode": "live"})
    server = LiveServer(hub, "0.0.0.0", 0, on_stop=lambda: stops.append(1) or "stopping")
    server.start()
    try:
        code, body = _post_stop(ip, server.port, {"X-Pmalab-Stop": "1"}, source=(ip, 0))
        assert code == 403 and "only from 127.0.0.1" in body["message"] and not stops
        assert '"stop_allowed":false' in _events_from(ip, server.port)
    finally:
        server.close(grace_s=0)


def _events_from(ip, port):
    conn = http.client.HTTPConnection(ip, port, timeout=5, source_address=(ip, 0))
    conn.request("GET", "/events")
    resp = conn.getresponse()
    line = ""
    while "stop_allowed" not in line:
        line = resp.fp.readline().decode()
    conn.close()
    return line


def test_a_busy_port_is_one_line():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen()
        port = s.getsockname()[1]
        with pytest.raises(ConfigError) as ei:
            LiveServer(Hub({}), "127.0.0.1", port)
    assert f"127.0.0.1:{port}: cannot serve the live view" in str(ei.value)


# ------------------------------------------------------------------ runner hook
def _channels(path):
    return {
        r.name: np.column_stack(
            [
                r.time,
                r.position,
                r.force,
                r.muscle_pressure,
                r.cylinder_pressure,
                r.cylinder_pressure_command,
            ]
        )
        for r in read_runs(path)
    }


def test_observed_recording_is_identical_and_a_failing_observer_is_ignored(tmp_path):
    proto = parse_protocol(TWO_RUNS, "t.toml")
    run_protocol(
        make_fake_rig(), proto, tmp_path / "plain.h5", options=RunnerOptions(progress=False)
    )
    _, events, feed, reader = _ring(100_000)
    run_protocol(
        make_fake_rig(),
        proto,
        tmp_path / "live.h5",
        options=RunnerOptions(progress=False, observer=feed),
    )
    plain, live = _channels(tmp_path / "plain.h5"), _channels(tmp_path / "live.h5")
    assert plain.keys() == live.keys()
    for name in plain:
        np.testing.assert_array_equal(plain[name], live[name])
    rows = reader.drain()  # the ring saw exactly what was recorded
    np.testing.assert_array_equal(rows[:, 2:], np.vstack([live["first"], live["second"]]))
    assert [e[0] for e in events] == ["start", "end", "start", "end"]
    assert events[1][2] == "completed"

    class Broken(RunObserver):
        def run_started(self, index, spec, writer):
            raise RuntimeError("display bug")

        def run_ended(self, index, spec, status, message):
            raise RuntimeError("display bug")

    (r1, r2) = run_protocol(
        make_fake_rig(),
        proto,
        tmp_path / "broken.h5",
        options=RunnerOptions(progress=False, observer=Broken()),
    )
    assert r1.status == r2.status == "completed"


def test_stop_request_is_a_safe_abort_that_keeps_the_samples(tmp_path):
    proto = parse_protocol(TWO_RUNS, "t.toml")
    rig = make_fake_rig()
    opts = RunnerOptions(progress=False)

    class StopAfter(RunObserver):  # presses stop after 300 samples of the first run
        def run_started(self, index, spec, writer):
            append = writer.append

            def tap(row, lateness):
                append(row, lateness)
                if writer.buffered + writer.n == 300:
                    opts.request_stop()

            writer.append = tap

        def run_ended(self, index, spec, status, message):
            self.ended = (status, message)

    opts.observer = obs = StopAfter()
    with pytest.raises(SafetyAbort) as ei:
        run_protocol(rig, proto, tmp_path / "stop.h5", options=opts)
    assert "run 'first' aborted: stopped from the live view" in str(ei.value)
    assert obs.ended[0] == "aborted: stopped from the live view"
    calls = rig.cylinder_regulator.calls
    first_vent = next(i for i, c in enumerate(calls) if c[1] == "vent")
    assert all(v == 0.0 for _, _, v in calls[first_vent:]) and calls[-1][1] == "vent"
    (run,) = read_runs(tmp_path / "stop.h5")
    assert run.attrs["status"] == "aborted: stopped from the live view" and len(run) == 300


# ------------------------------------------------------------------ pmalab view
def _record_partial(path, n_first):
    rec = Recorder(
        path,
        [
            (
                "a",
                {
                    "sample_rate_Hz": 500.0,
                    "frequency_Hz": 1.0,
                    "steady_start_s": 0.0,
                    "steady_end_s": 2.0,
                    "ramp_s": 0.0,
                },
            ),
            ("b", {"sample_rate_Hz": 500.0}),
        ],
        {"limits": json.dumps(LIMITS)},
    )
    w = rec.writer("a")
    w.set_status("running")
    for k in range(n_first):
        t = k / 500
        w.add(t, 20 + 5 * np.sin(2 * np.pi * t), 300.0, 0.4, 0.2, 0.2, 0.0)
    w.commit()
    return rec, w


def test_file_follower_reads_a_growing_file_then_a_finished_one(tmp_path):
    path = tmp_path / "growing.h5"
    rec, w = _record_partial(path, 500)
    hub = Hub({"mode": "view"})
    fol = FileFollower(path, hub)
    fol.poll()  # while the recorder holds the file open for writing (SWMR)
    assert fol.done == {0: 500} and not fol.complete
    assert hub.runs[0].n_points == 50 and hub.runs[0].status == "running"
    for k in range(500, 800):
        w.add(k / 500, 20.0, 310.0, 0.4, 0.2, 0.2, 0.0)
    w.finish("completed")
    rec.writer("b").set_status("not run: campaign aborted")
    rec.close()
    fol.poll()
    assert fol.done == {0: 800} and fol.complete and hub.runs[0].status == "completed"
    assert hub.runs[0].n_points == 80  # every 10th sample, on one grid across polls
    ts = [t for fr in hub.runs[0].frames for t in json.loads(fr.split(b"data: ")[1])["t"]]
    np.testing.assert_allclose(ts, np.arange(0, 800, 10) / 500)
    assert "complete" in hub.end_message


def test_view_command_serves_a_recorded_file_until_interrupted(tmp_path):
    rec, w = _record_partial(tmp_path / "done.h5", 600)
    w.finish("completed")
    rec.writer("b").set_status("not run: campaign aborted")
    rec.close()
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(p for p in sys.path if p)}
    proc = subprocess.Popen(
        [sys.executable, "-m", "pmalab.cli", "view", str(tmp_path / "done.h5"), "--no-browser"],
        stderr=subprocess.PIPE,
        text=True,
        env=env,
    )
    try:
        line = ""
        while "viewing" not in line and proc.poll() is None:
            line = proc.stderr.readline()
        assert "viewing" in line and "http://127.0.0.1:" in line
        port = int(line.split("http://127.0.0.1:", 1)[1].split("/", 1)[0])
        text = _events(port, until="end")
        assert '"mode":"view"' in text and '"stop_allowed":false' in text
        assert text.count("event: points") >= 1
        assert '"message":"done.h5: complete (1 run with samples)"' in text
    finally:
        proc.send_signal(signal.SIGTERM)  # (SIGINT may be ignored by a parent shell)
        proc.communicate(timeout=20)
    assert proc.returncode == 0


def test_view_of_a_missing_or_foreign_file_is_one_line(tmp_path, capsys):
    from pmalab.cli import main

    (tmp_path / "x.h5").write_text("not hdf5")
    for name, why in (("missing.h5", "no such file"), ("x.h5", "not a readable HDF5 file")):
        assert main(["view", str(tmp_path / name), "--no-browser"]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and why in err and name in err


def test_run_with_a_busy_live_port_fails_before_anything_moves(tmp_path, capsys):
    from pmalab.cli import main

    out = tmp_path / "o.h5"
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen()
        port = s.getsockname()[1]
        assert (
            main(
                [
                    "run",
                    "--rig",
                    "sim",
                    "--protocol",
                    "quick",
                    "--out",
                    str(out),
                    "--live",
                    str(port),
                    "--quiet",
                ]
            )
            == 2
        )
    err = capsys.readouterr().err
    assert f"--live 127.0.0.1:{port}: cannot serve the live view" in err
    assert err.count("\n") == 1 and not out.exists()


def test_run_with_a_bad_live_address_fails_before_anything_is_created(tmp_path, capsys):
    from pmalab.cli import main

    out = tmp_path / "o.h5"
    assert (
        main(["run", "--rig", "sim", "--protocol", "quick", "--out", str(out), "--live", "nope"])
        == 2
    )
    assert "--live: port must be an integer" in capsys.readouterr().err
    assert not out.exists()


def test_view_of_a_file_still_being_written_quits_cleanly(tmp_path):
    rec, w = _record_partial(tmp_path / "growing.h5", 600)  # held open for writing (SWMR)
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(p for p in sys.path if p)}
    proc = subprocess.Popen(
        [sys.executable, "-m", "pmalab.cli", "view", str(tmp_path / "growing.h5"), "--no-browser"],
        stderr=subprocess.PIPE,
        text=True,
        env=env,
    )
    try:
        line = ""
        while "viewing" not in line and proc.poll() is None:
            line = proc.stderr.readline()
        port = int(line.split("http://127.0.0.1:", 1)[1].split("/", 1)[0])
        text = _events(port, until="status")
        assert '"phase":"recording"' in text
        for k in range(600, 900):  # it grows while the page is open
            w.add(k / 500, 20.0, 310.0, 0.4, 0.2, 0.2, 0.0)
        w.commit()
        deadline = time.monotonic() + 20
        while '"samples":900' not in text and time.monotonic() < deadline:
            time.sleep(0.2)
            text = _events(port, until="status")
        assert '"samples":900' in text  # the page saw the file grow
    finally:
        proc.send_signal(signal.SIGTERM)  # quits while its follower polls a growing file
        proc.communicate(timeout=20)
        w.finish("completed")
        rec.writer("b").set_status("not run: campaign aborted")
        rec.close()
    assert proc.returncode == 0


def test_run_events_never_block_the_runner_when_the_display_stops_reading():
    from pmalab.acquisition.live.process import DisplayProcess

    d = DisplayProcess({}, 16, on_stop=lambda: None)
    d.proc = subprocess.Popen(
        [sys.executable, "-c", "import time; time.sleep(60)"], stdin=subprocess.PIPE
    )  # a display that hangs
    os.set_blocking(d.proc.stdin.fileno(), False)
    try:
        t0 = time.monotonic()
        for k in range(2000):  # ~1 MB of run events: far more than a pipe holds
            d.send(("end", k, "aborted: " + "x" * 5000, "message " * 100))
        assert time.monotonic() - t0 < 5 and d.lost_events > 0
    finally:
        d.proc.kill()
        d.proc.wait()
        d.close("")


def test_stop_while_waiting_for_the_muscle_pressure_aborts_before_recording(tmp_path):
    proto = parse_protocol(TWO_RUNS, "t.toml")
    rig = make_fake_rig()
    opts = RunnerOptions(progress=False)

    class StopAtStart(RunObserver):
        def run_started(self, index, spec, writer):
            opts.request_stop()  # pressed before the pressure settled

    opts.observer = StopAtStart()
    with pytest.raises(SafetyAbort) as ei:
        run_protocol(rig, proto, tmp_path / "early.h5", options=opts)
    assert "run 'first' aborted: stopped from the live view" in str(ei.value)
    assert rig.cylinder_regulator.calls[-1][1] == "vent"
    assert max(v for _, _, v in rig.cylinder_regulator.calls) == 0.0  # nothing moved
