"""Active identification appends a round's runs to the campaign in place: the campaign's
own runs are neither copied nor rewritten, /runs only ever holds whole runs."""

from __future__ import annotations

import os

import h5py
import numpy as np
import pytest

from pmalab.active.loop import STAGING, ActiveError, append_runs
from pmalab.runfile import Run, read_runs, write_runs


def _run(name: str, n: int = 2000, seed: int = 0) -> Run:
    rng = np.random.default_rng(seed)
    t = np.arange(n) / 500.0
    x = 10 + 5 * np.sin(2 * np.pi * 0.5 * t)
    return Run(name, t, x, 400 - 20 * x + rng.normal(0, 0.5, n), np.full(n, 0.4),
               attrs={"muscle_pressure_MPa": 0.4, "frequency_Hz": 0.5})


def _offsets(path, names):
    with h5py.File(path, "r") as f:
        return {n: f[f"runs/{n}/force"].id.get_offset() for n in names}


def test_a_round_is_appended_in_place_without_copying_the_campaign(tmp_path):
    camp = write_runs(tmp_path / "c.h5", [_run("a"), _run("b", seed=1)])
    rnd = write_runs(tmp_path / "r.h5", [_run("a", seed=2), _run("c", seed=3)])
    before = _offsets(camp, ["a", "b"])
    ino = os.stat(camp).st_ino
    # a copy a crash left in the staging group is dropped, never read as a run
    with h5py.File(camp, "a") as f:
        f.create_group(f"{STAGING}/half")
    added = append_runs(camp, rnd, ["a", "c"])
    assert added == ["a-2", "c"]
    assert os.stat(camp).st_ino == ino  # the same file, not a renamed copy
    assert _offsets(camp, ["a", "b"]) == before  # its own runs' data untouched
    with h5py.File(camp, "r") as f:
        assert STAGING not in f
        assert f["runs/c"].attrs["appended_from"] == b"r.h5"  # fixed-length UTF-8 text
    got = {r.name: r for r in read_runs(camp)}
    assert sorted(got) == ["a", "a-2", "b", "c"]
    src = {r.name: r for r in read_runs(rnd)}
    np.testing.assert_array_equal(got["a-2"].force, src["a"].force)


def test_a_failed_append_leaves_the_campaign_runs_as_they_were(tmp_path):
    camp = write_runs(tmp_path / "c.h5", [_run("a")])
    rnd = write_runs(tmp_path / "r.h5", [_run("c", seed=3)])
    with pytest.raises(ActiveError, match="runs c were appended before it"):
        append_runs(camp, rnd, ["c", "missing"])
    with h5py.File(camp, "r") as f:
        assert STAGING not in f
    assert sorted(r.name for r in read_runs(camp)) == ["a", "c"]  # whole runs only
