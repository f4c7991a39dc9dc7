"""Property-based robustness of every reader (Hypothesis): damaged or absurd input gives one
clear line and exit 2, never a traceback and never a partial output file.

For each importer (text, TDMS, MATLAB v5, MATLAB v7.3) and for the run-file reader, a valid
file is written with its real library and then damaged at random: truncated at any byte,
bytes overwritten, or values replaced by NaN, ±inf, huge numbers or text.  The number of
cases tried is checked at the end (and printed with ``pytest -s``).
"""

from __future__ import annotations

import contextlib
import io
from collections import Counter
from pathlib import Path

import h5py
import numpy as np
import pytest
import scipy.io
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from nptdms import ChannelObject, GroupObject, TdmsWriter

from pmalab.cli import main as pmalab_main
from pmalab.errors import PmalabError
from pmalab.runfile import Run, read_runs, write_runs

TRIED: Counter[str] = Counter()
N = 200
SETTINGS = settings(max_examples=60, deadline=None, derandomize=True,
                    suppress_health_check=[HealthCheck.function_scoped_fixture])

ODD = st.sampled_from([np.nan, np.inf, -np.inf, 1e300, -1e300, 0.0, 1e-300, 7e4])


def _cli(args) -> tuple[int, str]:
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = pmalab_main([str(a) for a in args])
    return code, err.getvalue()


def _signals() -> dict[str, np.ndarray]:
    t = np.arange(N) * 0.002
    x = 15.0 * np.sin(2 * np.pi * t)
    return {"time": t, "position": x, "force": 500 + 8 * x,
            "muscle_pressure": np.full(N, 0.4)}


def _check(tmp: Path, src: Path, extra: list[str], kind: str) -> None:
    out = tmp / f"out-{kind}.h5"
    out.unlink(missing_ok=True)
    code, err = _cli(["import", src, *extra, "--out", out])
    TRIED[kind] += 1
    assert code in (0, 2), err
    assert "Traceback" not in err
    if code == 2:
        assert err.count("\n") == 1 and err.startswith("pmalab import: error: "), err
        assert not out.exists()  # a failed import leaves nothing behind
    else:
        assert out.exists()


def _damage(data: bytes, how: str, at: float, blob: bytes) -> bytes:
    k = int(at * len(data))
    if how == "truncate":
        return data[:k]
    return data[:k] + blob + data[k + len(blob):]


DAMAGE = st.tuples(st.sampled_from(["truncate", "overwrite"]), st.floats(0, 1),
                   st.binary(min_size=1, max_size=64))


def _write_tdms(path: Path, sig: dict[str, np.ndarray]) -> None:
    with TdmsWriter(str(path)) as w:
        w.write_segment([GroupObject("g")] + [ChannelObject("g", k, v) for k, v in sig.items()])


def _write_v73(path: Path, sig: dict[str, np.ndarray]) -> None:
    with h5py.File(path, "w", userblock_size=512) as f:
        g = f.create_group("run1")
        g.attrs["MATLAB_class"] = np.bytes_("struct")
        for k, v in sig.items():
            g.create_dataset(k, data=np.atleast_2d(v))
    with path.open("r+b") as fh:
        fh.write(b"MATLAB 7.3 MAT-file".ljust(124) + b"\x00\x02IM")


WRITERS = {
    "text": (lambda p, s: p.write_text("time,position,force,muscle_pressure\n" + "\n".join(
        ",".join(repr(float(s[c][i])) for c in ("time", "position", "force", "muscle_pressure"))
        for i in range(N)) + "\n"), ".csv"),
    "tdms": (_write_tdms, ".tdms"),
    "mat5": (lambda p, s: scipy.io.savemat(p, {"run1": s}), ".mat"),
    "mat73": (_write_v73, ".mat"),
}


@pytest.mark.parametrize("kind", sorted(WRITERS))
def test_damaged_files_give_one_line(tmp_path, kind):
    write, suffix = WRITERS[kind]
    good = tmp_path / f"good{suffix}"
    write(good, _signals())
    data = good.read_bytes()

    @SETTINGS
    @given(DAMAGE)
    def check(damage):
        bad = tmp_path / f"bad{suffix}"
        bad.write_bytes(_damage(data, *damage))
        _check(tmp_path, bad, [], f"{kind} bytes")

    check()


@pytest.mark.parametrize("kind", sorted(WRITERS))
def test_absurd_values_are_refused_or_read_never_crash(tmp_path, kind):
    write, suffix = WRITERS[kind]

    @SETTINGS
    @given(st.sampled_from(["time", "position", "force", "muscle_pressure"]),
           st.lists(st.tuples(st.integers(0, N - 1), ODD), min_size=1, max_size=5),
           st.sampled_from([1.0, 1e-3, 1e3, -1.0]))
    def check(channel, cells, scale):
        sig = _signals()
        sig[channel] = sig[channel] * scale
        for i, v in cells:
            sig[channel][i] = v
        src = tmp_path / f"odd{suffix}"
        src.unlink(missing_ok=True)
        write(src, sig)
        _check(tmp_path, src, [], f"{kind} values")

    check()


def test_damaged_run_files_raise_one_line(tmp_path):
    s = _signals()
    good = tmp_path / "good.h5"
    write_runs(good, [Run(name="r", attrs={"muscle_pressure_MPa": 0.4}, **s)])
    data = good.read_bytes()

    @SETTINGS
    @given(DAMAGE)
    def check(damage):
        bad = tmp_path / "bad.h5"
        bad.write_bytes(_damage(data, *damage))
        TRIED["run file bytes"] += 1
        try:
            runs = read_runs(bad)
        except PmalabError as exc:
            assert "\n" not in str(exc).strip() and str(bad) in str(exc), str(exc)
            return
        assert all(len(r.time) == len(r.force) for r in runs)

    check()


def test_zz_cases_tried():
    """Runs last (file order): every reader was tried on many cases."""
    total = sum(TRIED.values())
    print(f"\nrobustness cases tried: {total} ({dict(TRIED)})")
    assert len(TRIED) == 9 and min(TRIED.values()) >= 20, TRIED
