"""``predictions.h5`` has one writer: identify's and diagnose's files have the same layout
(every dataset with its unit, the same attrs) and the report reads both."""

from __future__ import annotations

import contextlib
import io

import h5py
import pytest

from pmalab.cli import main as pmalab_main
from pmalab.identify.predictions import PREDICTIONS_FORMAT
from pmalab.paths import RIGS_DIR
from pmalab.reports.data import read_predictions


def _cli(args) -> int:
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
        return pmalab_main([str(a) for a in args])


@pytest.fixture(scope="module")
def outputs(tmp_path_factory):
    d = tmp_path_factory.mktemp("pred")
    camp = d / "c.h5"
    assert _cli(["run", "--rig", RIGS_DIR / "sim.toml", "--protocol", "diagnosis-test", "--out",
                 camp, "-q"]) == 0
    assert _cli(["identify", camp, "--model", "bouc-wen", "--out", d / "i", "-q"]) == 0
    assert _cli(["diagnose", camp, "--model", "bouc-wen", "--out", d / "g", "--only",
                 "viscous-friction", "--laws", "none", "-q"]) == 0
    return d / "i" / "predictions.h5", d / "g" / "predictions.h5"


def test_both_writers_write_one_layout_with_units(outputs):
    attrs = {"role", "file", "run", "muscle_pressure_MPa", "frequency_Hz", "waveform", "model"}
    for path in outputs:
        with h5py.File(path) as f:
            assert f.attrs["format"] == PREDICTIONS_FORMAT and f.attrs["format_version"] == 1
            assert "model" in f.attrs
            for g in f["runs"].values():
                assert attrs <= set(g.attrs)
                for ds in ("time", "position", "muscle_pressure", "force", "force_model"):
                    assert g[ds].attrs["units"] in ("s", "mm", "MPa", "N"), (path, ds)
    roles = {t.role for t in read_predictions(outputs[1])}
    assert roles == {"diagnosis", "diagnosis-final"}
    assert {t.role for t in read_predictions(outputs[0])} == {"identification", "validation"}
