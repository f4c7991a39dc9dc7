"""A run file whose writer is alive: a run still marked ``running`` is being recorded, not
killed.  Its last chunk is rewritten at every flush, so a reader must neither call a chunk
it meets mid-rewrite torn nor its samples lost: the run is read to the samples flushed so
far and said to be recording; ``recover`` refuses to touch the file and ``check`` says the
run is not checked yet.  Once the writer is killed, the same file reads as a killed
recording again."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from pathlib import Path

import h5py
import pytest

from pmalab.acquisition.check import report
from pmalab.acquisition.recover import recover
from pmalab.errors import RunFileError, RunFileWarning
from pmalab.runfile import read_run_datasets, read_runs
from pmalab.writer_process import alive, identity

REPO = Path(__file__).resolve().parents[1]
N_B = 4200  # run 'b': one full chunk of 4096 samples, then 104 in the chunk each flush rewrites

WRITE = f"""
import sys
import numpy as np
from pmalab.acquisition.recorder import Recorder
rec = Recorder(sys.argv[1], [(r, {{"muscle_pressure_MPa": 0.4}}) for r in "abc"], {{}})
rng = np.random.default_rng(7)
for name, n in (("a", 1000), ("b", {N_B})):
    w = rec.writer(name)
    w.set_status("running")
    for i in range(n):
        w.add(i * 0.002, 10.0 + rng.normal(), 400.0 + 50 * rng.normal(), 0.4, 0.1, 0.1, 0.0)
        if i % 125 == 124:
            w.commit()
    w.commit()
    if name == "a":
        w.finish("completed")
print("ready", flush=True)
sys.stdin.read()  # recording 'b' until the test ends it
"""


@pytest.fixture
def live(tmp_path):
    out = tmp_path / "live.h5"
    proc = subprocess.Popen([sys.executable, "-c", WRITE, str(out)], cwd=REPO, text=True,
                            stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                            env={**os.environ, "PYTHONPATH": str(REPO)})
    try:
        assert proc.stdout is not None and proc.stdout.readline().strip() == "ready"
        yield out, proc
    finally:
        proc.kill()
        proc.wait(timeout=30)


def _messages(caught) -> list[str]:
    return [str(w.message) for w in caught]


def test_a_run_being_recorded_is_read_as_flushed_and_said_to_be_recording(live):
    out, proc = live
    writer = f"process {proc.pid} on {os.uname().nodename}"
    with pytest.warns(RunFileWarning) as caught:
        runs = read_runs(out)
    assert [(r.name, len(r)) for r in runs] == [("a", 1000), ("b", N_B)]
    assert _messages(caught) == [
        f"{out}: still being recorded by {writer}: read run 'b' ({N_B} samples flushed so "
        "far); 1 run(s) not recorded yet: c"
    ]
    with pytest.warns(RunFileWarning) as caught:
        assert [r.name for r in read_runs(out, skip_incomplete=True)] == ["a"]
    assert f"{out}: run 'b' skipped: still being recorded by {writer} (--include-aborted " \
           "uses it anyway)" in _messages(caught)
    assert len(read_run_datasets(out, "b")["force"][0]) == N_B
    with pytest.raises(RunFileError, match=r"still being recorded.*nothing to recover"):
        recover(out)
    assert sorted(p.name for p in out.parent.iterdir()) == ["live.h5"]
    lines, _ = report(out)
    assert f"  run 'b': still being recorded by {writer}, {N_B} samples so far: not checked " \
           "until it ends" in lines, lines


def test_a_chunk_met_mid_rewrite_is_not_called_torn_while_its_writer_records(live):
    out, proc = live
    with h5py.File(out, "r", swmr=True) as h:  # the chunk the next flush rewrites
        info = h["runs/b/force"].id.get_chunk_info_by_coord((4096,))
    with open(out, "r+b") as fh:  # as a reader may meet it while the writer's pwrite runs
        fh.seek(info.byte_offset + 8)
        fh.write(b"\x7f" * 8)
    with pytest.warns(RunFileWarning) as caught:
        (b,) = read_runs(out, runs=["b"])
    assert len(b) == 4096  # the samples every checksum verifies, none invented
    rewrite = [m for m in _messages(caught) if "last chunk of 'force'" in m]
    assert rewrite == [
        f"{out}: run 'b': the last chunk of 'force' (samples 4096..{N_B - 1}) is being "
        f"rewritten by process {proc.pid} on {os.uname().nodename}, which still records the "
        "run: read to its first 4096 samples; the rest are not lost (read again once the "
        "flush is done)"
    ]
    # the writer killed: the same chunk is what the kill left, and the reader says so
    proc.send_signal(signal.SIGKILL)
    proc.wait(timeout=30)
    with pytest.warns(RunFileWarning) as caught:
        (b,) = read_runs(out, runs=["b"])
    assert len(b) == 4096
    assert any("torn by the kill" in m and f"({N_B - 4096} lost)" in m
               for m in _messages(caught))


def test_the_writer_is_this_process_while_it_runs_and_no_other():
    me = identity()
    assert alive(me) == f"process {os.getpid()} on {os.uname().nodename}"
    child = subprocess.run([sys.executable, "-c",
                            "from pmalab.writer_process import identity; print(identity())"],
                           capture_output=True, text=True, check=True, cwd=REPO)
    assert alive(child.stdout.strip()) is None  # ended
    reused = me.replace('"start_ticks": ', '"start_ticks": 1')  # same pid, another start
    assert alive(reused) is None
    assert alive(None) is None and alive("not json") is None


def test_a_pid_of_another_pid_namespace_is_not_this_writer():
    """A container has its own pids: the recording's pid 7 there is not this namespace's
    pid 7, even on the same host (its name shared with host networking) and boot."""
    import json

    me = json.loads(identity())
    assert me["pid_ns"].startswith("pid:[")
    assert alive(json.dumps({**me, "pid_ns": "pid:[1]"})) is None
    assert alive(json.dumps({k: v for k, v in me.items() if k != "pid_ns"})) is None
    assert alive(json.dumps(me)) == f"process {os.getpid()} on {os.uname().nodename}"


def test_a_run_being_recorded_with_damaged_attributes_is_said_damaged(monkeypatch):
    """A live run's samples are not checked (their last chunk is rewritten at every
    flush), but its attributes were sealed before the first sample: a checksum that fails
    there is damage, reported and failing the check, not hidden behind "being recorded"."""
    from pmalab.acquisition import check

    rc = check.RunCheck("b", recording="process 7 on lab-pc", samples=4200)
    rc.damaged.append("attributes (checksum does not match)")
    monkeypatch.setattr(check, "check_file", lambda path: ([], [rc], None))
    lines, ok = check.report("live.h5")
    assert not ok
    assert "  run 'b': DAMAGED: attributes (checksum does not match)" in lines, lines
    assert lines[-1] == "live.h5: 0 of 1 runs intact, 1 still being recorded"
