"""Work that several test files need exactly as it is, made once per test session.

Under pytest-xdist every worker of a session sees the same directory (beside the workers'
own temporary directories); the first test that wants an item makes it there under a lock
file and every other test, in this worker or another, waits for it and reads it.  Nothing
a test reads from here may be changed by it (copy it first).
"""

from __future__ import annotations

import contextlib
import fcntl
import io
import os
import shutil
from collections.abc import Callable
from pathlib import Path

import pytest
from sim_campaign import record_campaign

from pmalab.cli import main as pmalab_main
from pmalab.paths import TRUTH_DIR


def _session_dir(factory: pytest.TempPathFactory) -> Path:
    base = factory.getbasetemp()
    if os.environ.get("PYTEST_XDIST_WORKER"):
        base = base.parent  # the session's directory, shared by its workers
    d = base / "shared-work"
    d.mkdir(exist_ok=True)
    return d


def made_once(factory: pytest.TempPathFactory, name: str, make: Callable[[Path], None]) -> Path:
    """The directory ``name`` of this session's shared work, ``make(directory)`` having
    filled it (here, or by another test of the session, before)."""
    root = _session_dir(factory)
    d = root / name
    with open(root / f"{name}.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        if not (d / ".done").exists():
            shutil.rmtree(d, ignore_errors=True)  # a maker that failed left it half made
            d.mkdir()
            make(d)
            (d / ".done").write_text("")
    return d


def _cli(argv: list[str]) -> tuple[int, str]:
    """Exit code, and what was printed: the standard output, then the standard error."""
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        rc = pmalab_main(argv)
    return rc, out.getvalue() + err.getvalue()


#: the laws of :func:`maxwell_slip_four_laws`, in the order they are given
FOUR_LAWS = ("bouc-wen", "duhem", "prandtl-ishlinskii", "maxwell-slip")


def maxwell_slip_four_laws(factory: pytest.TempPathFactory) -> tuple[Path, Path, str]:
    """The diagnosis-test campaign on the muscle whose braid friction is Maxwell-slip-shaped
    (data/truth/hysteresis-maxwell-slip.toml, sensor seed 7) and ``pmalab identify c.h5
    --model bouc-wen,duhem,prandtl-ishlinskii,maxwell-slip --out laws`` of it (its held-out
    runs validate): the campaign file, the laws directory and what identify printed."""

    def make(d: Path) -> None:
        record_campaign(TRUTH_DIR / "hysteresis-maxwell-slip.toml", d, 7, name="c.h5")
        rc, text = _cli(["identify", str(d / "c.h5"), "--model", ",".join(FOUR_LAWS), "--out",
                         str(d / "laws"), "--jobs", "1"])  # in process: a worker per core
        assert rc == 0, text
        (d / "identify.txt").write_text(text)

    d = made_once(factory, "maxwell-slip-four-laws", make)
    return d / "c.h5", d / "laws", (d / "identify.txt").read_text()
