"""The run-file contract: round trip, unit conversion, one clear error per malformed input."""

from __future__ import annotations

import h5py
import numpy as np
import pytest

from pmalab.errors import OutputExistsError, RunFileError
from pmalab.runfile import Run, read_runs, write_runs


def _run(n: int = 100) -> Run:
    t = np.arange(n) / 500.0
    return Run(
        name="r0",
        time=t,
        position=10 + np.sin(t),
        force=800 - 30 * np.sin(t),
        muscle_pressure=np.full(n, 0.4),
        attrs={"muscle_pressure_MPa": 0.4, "waveform": "sine", "frequency_Hz": 0.15,
               "sample_rate_Hz": 500.0, "protocol": {"k": 1}},
    )


def test_round_trip(tmp_path):
    p = write_runs(tmp_path / "a.h5", [_run()])
    (r,) = read_runs(p)
    assert r.name == "r0" and r.attrs["protocol"] == {"k": 1}
    np.testing.assert_allclose(r.force, _run().force)
    assert r.to_dataframe().shape == (100, 4)
    with pytest.raises(OutputExistsError):
        write_runs(p, [_run()])


def _patch(tmp_path, fn):
    p = write_runs(tmp_path / "b.h5", [_run()])
    with h5py.File(p, "a") as f:
        fn(f["runs/r0"])
        del f["runs/r0"].attrs["attrs_sha256"]  # edited by another tool: no digest
    return p


def test_units_are_converted(tmp_path):
    def to_si(g):
        for ch, fac, unit in [("position", 1e-3, "m"), ("muscle_pressure", 1e3, "kPa"),
                              ("time", 1e3, "ms"), ("force", 1e-3, "kN")]:
            data = g[ch][()] * fac
            del g[ch]
            g.create_dataset(ch, data=data).attrs["units"] = unit
    (r,) = read_runs(_patch(tmp_path, to_si))
    ref = _run()
    for ch in ("time", "position", "force", "muscle_pressure"):
        np.testing.assert_allclose(getattr(r, ch), getattr(ref, ch), rtol=1e-12)


@pytest.mark.parametrize(
    "mutate, needle",
    [
        (lambda g: g.__delitem__("force"), "channel 'force': missing channel"),
        (lambda g: g["force"].attrs.__setitem__("units", "lbf"), "unknown unit 'lbf'"),
        (lambda g: g["position"].attrs.__delitem__("units"), "missing 'units'"),
        (lambda g: (g.__delitem__("force"), g.create_dataset("force", data=np.ones(99)).attrs.__setitem__("units", "N")), "unequal lengths"),
        (lambda g: g["time"].__setitem__(5, 0.0), "not strictly increasing"),
        (lambda g: g["force"].__setitem__(7, np.nan), "NaN"),
    ],
)
def test_malformed_inputs_name_file_run_channel(tmp_path, mutate, needle):
    p = _patch(tmp_path, mutate)
    with pytest.raises(RunFileError) as ei:
        read_runs(p)
    msg = str(ei.value)
    assert needle in msg and "b.h5" in msg and "run 'r0'" in msg and "\n" not in msg


def test_not_hdf5(tmp_path):
    p = tmp_path / "x.h5"
    p.write_text("hello")
    with pytest.raises(RunFileError, match="not a readable HDF5 file"):
        read_runs(p)


def test_steady_window_trims_settle_and_ramps():
    r = _run(1000)  # 2 s at 500 Hz
    r.attrs.update(steady_start_s=0.5, steady_end_s=1.5)
    s = r.steady()
    assert abs(s.time[0] - 0.5) < 2e-3 and abs(s.time[-1] - 1.5) < 2e-3
    assert len(s) == 501 and s.attrs["window_s"] == [0.5, 1.5]
    np.testing.assert_array_equal(s.force, r.force[250:751])
    del r.attrs["steady_start_s"]
    assert r.steady() is r  # imported runs without the window stay whole
