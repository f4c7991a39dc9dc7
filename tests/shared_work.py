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
import pickle
import shutil
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

import pytest
from sim_campaign import record_campaign

from pmalab.cli import main as pmalab_main
from pmalab.paths import TRUTH_DIR

if TYPE_CHECKING:
    from pmalab.identify.outputs import Identification


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
    d = made_once(factory, "maxwell-slip-four-laws", _make_four_laws)
    return d / "c.h5", d / "laws", (d / "identify.txt").read_text()


def maxwell_slip_identifications(factory: pytest.TempPathFactory) -> dict[str, Identification]:
    """The identifications :func:`maxwell_slip_four_laws`'s ``pmalab identify`` made, law by
    law, as :func:`pmalab.identify.api.identify` returned them to the command (a fresh copy
    per call: a test may change its own).  Each is ``identify(runs, law, validate=held_out)``
    of the campaign's runs; its campaign fit is ``identify(identification_runs, law)``'s,
    number for number (validation only reads the fit)."""
    d = made_once(factory, "maxwell-slip-four-laws", _make_four_laws)
    with open(d / "identifications.pickle", "rb") as f:
        return pickle.load(f)


def _make_four_laws(d: Path) -> None:
    import pmalab.identify.api as api

    record_campaign(TRUTH_DIR / "hysteresis-maxwell-slip.toml", d, 7, name="c.h5")
    made: dict[str, Identification] = {}
    identify = api.identify

    def kept(runs, model, *args, **kwargs):  # the command's own call, its result kept
        res = identify(runs, model, *args, **kwargs)
        made[model] = res
        return res

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(api, "identify", kept)
        rc, text = _cli(["identify", str(d / "c.h5"), "--model", ",".join(FOUR_LAWS), "--out",
                         str(d / "laws"), "--jobs", "1"])  # in process: a worker per core
    assert rc == 0, text
    assert sorted(made) == sorted(FOUR_LAWS), sorted(made)
    (d / "identify.txt").write_text(text)
    with open(d / "identifications.pickle", "wb") as f:
        pickle.dump(made, f)
