"""The parallel paths (candidate scoring, per-run fits) under every start method.

Python 3.14 starts worker processes with forkserver on Linux and macOS uses spawn: a worker
then inherits nothing from the parent, so any state it needs must travel as an argument.
Each start method must give the same numbers as the in-process path."""

from __future__ import annotations

import multiprocessing

import numpy as np
import pytest
from identify_synth import make_run

from pmalab.identify.campaign import ModelSpec
from pmalab.identify.campaign.batch import START_METHOD_ENV, map_with_context
from pmalab.identify.campaign.fit import fit_runs
from pmalab.identify.diagnosis.ranking import score_all

METHODS = [m for m in ("fork", "forkserver", "spawn") if m in multiprocessing.get_all_start_methods()]


def _runs():
    train = [make_run("bouc-wen", p, f=0.5, n=3000, seed=i, name=f"id{i}")[0]
             for i, p in enumerate((0.3, 0.45, 0.6))]
    held = [make_run("bouc-wen", 0.4, f=0.4, n=3000, seed=9, name="held")[0]]
    return train, held


SPECS = [ModelSpec("bouc-wen", ()), ModelSpec("bouc-wen", ("viscous-friction",))]


@pytest.fixture(scope="module")
def serial():
    train, held = _runs()
    return score_all(train, held, SPECS, jobs=1)


def _scale(context: tuple[float, float], x: float) -> float:
    return context[0] * x + context[1]


@pytest.mark.parametrize("method", METHODS)
def test_score_all_parallel(method, monkeypatch, serial):
    monkeypatch.setenv(START_METHOD_ENV, method)
    train, held = _runs()
    par = score_all(train, held, SPECS, jobs=2)
    assert [s.effects for s in par] == [s.effects for s in serial]
    for a, b in zip(par, serial):
        np.testing.assert_allclose(a.nrmse, b.nrmse, rtol=1e-9)
        assert a.n_params == b.n_params


@pytest.mark.parametrize("method", METHODS)
def test_fit_runs_parallel(method, monkeypatch):
    monkeypatch.setenv(START_METHOD_ENV, method)
    train, _ = _runs()
    spec = ModelSpec("bouc-wen", ("viscous-friction",))  # an effect: the pool is used
    par = fit_runs(train, spec, jobs=2)
    one = fit_runs(train, spec, jobs=1)
    assert [r.label for r in par] == ["id0", "id1", "id2"]
    for a, b in zip(par, one):
        np.testing.assert_allclose(a.nrmse, b.nrmse, rtol=1e-9)


def test_unknown_start_method_is_one_line(monkeypatch):
    from pmalab.errors import PmalabError

    monkeypatch.setenv(START_METHOD_ENV, "teleport")
    with pytest.raises(PmalabError, match="teleport"):
        map_with_context(_scale, (1.0, 0.0), [1.0, 2.0], jobs=2)
