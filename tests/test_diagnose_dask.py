"""``pmalab diagnose --scheduler``: the candidates' identifications on a real Dask cluster
(a ``dask scheduler`` and a ``dask worker`` process, as a lab starts them) give the same
ranking and ladder as a local run."""

from __future__ import annotations

import contextlib
import io
import json
import shutil
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

from pmalab.cli import main as pmalab_main
from pmalab.paths import RIGS_DIR

pytestmark = pytest.mark.slow


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _cli(args) -> int:
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
        return pmalab_main([str(a) for a in args])


@pytest.fixture(scope="module")
def cluster(tmp_path_factory):
    dask = shutil.which("dask", path=str(Path(sys.executable).parent))
    if dask is None:
        pytest.skip("the dask command is not installed")
    port = _free_port()
    addr = f"tcp://127.0.0.1:{port}"
    log = tmp_path_factory.mktemp("dask")
    sched = subprocess.Popen([dask, "scheduler", "--host", "127.0.0.1", "--port", str(port),
                              "--no-dashboard"], stdout=open(log / "s.log", "w"),
                             stderr=subprocess.STDOUT)
    worker = subprocess.Popen([dask, "worker", addr, "--nworkers", "1", "--nthreads", "1",
                               "--no-dashboard"], stdout=open(log / "w.log", "w"),
                              stderr=subprocess.STDOUT)
    try:
        from distributed import Client

        deadline = time.monotonic() + 60
        while True:
            try:
                with Client(addr, timeout="2s") as c:
                    if c.scheduler_info()["workers"]:
                        break
            except OSError:
                pass
            if time.monotonic() > deadline:
                pytest.fail("the Dask cluster did not start: " + (log / "w.log").read_text())
            time.sleep(0.5)
        yield addr
    finally:
        # the worker first, while its scheduler still answers: stopped together, the
        # worker's nanny sometimes waits out its reports to a scheduler already gone
        # (8 s of an idle core in the suite; 0.5 s this way)
        worker.terminate()
        worker.wait(20)
        sched.terminate()
        sched.wait(20)


def test_diagnose_on_a_dask_cluster_gives_the_local_numbers(cluster, tmp_path):
    camp = tmp_path / "c.h5"
    assert _cli(["run", "--rig", RIGS_DIR / "sim-viscous-friction.toml", "--protocol",
                 "diagnosis-test", "--out", camp, "--quiet"]) == 0
    common = ["diagnose", camp, "--model", "bouc-wen", "--only", "viscous-friction",
              "--only", "sensor-delay", "--only", "inertia", "--laws", "duhem", "--quiet"]
    assert _cli([*common, "--out", tmp_path / "local", "--jobs", "1"]) == 0
    assert _cli([*common, "--out", tmp_path / "dask", "--scheduler", cluster]) == 0
    a = json.loads((tmp_path / "local" / "diagnosis.json").read_text())
    b = json.loads((tmp_path / "dask" / "diagnosis.json").read_text())
    assert [s["added"] for s in a["ladder"]] == [s["added"] for s in b["ladder"]]
    assert a["ladder"][1]["added"] == "viscous-friction"
    for sa, sb in zip(a["ladder"], b["ladder"]):
        assert sb["nrmse"] == pytest.approx(sa["nrmse"], rel=1e-9)
    assert [r["nrmse_after"] for r in b["ranking"]] == pytest.approx(
        [r["nrmse_after"] for r in a["ranking"]], rel=1e-9)
