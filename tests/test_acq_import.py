"""``pmalab import``: CSV from another DAQ → contract file (column mapping, units, errors)."""

from __future__ import annotations

import numpy as np
import pytest

from pmalab.acquisition.csv_import import CsvImportOptions, parse_units, read_csv_run
from pmalab.cli import main
from pmalab.errors import RunFileError
from pmalab.runfile import read_runs

N = 400


def _signals():
    t = np.arange(N) / 500.0
    x = 15.0 + 5.0 * np.sin(2 * np.pi * 0.5 * t)  # mm contraction
    f = 400.0 - 20.0 * (x - 15.0)  # N tension
    p = np.full(N, 0.45)  # MPa
    return t, x, f, p


def _write_csv(path, header, cols, fmt="%.9g", sep=","):
    data = np.column_stack(cols)
    lines = [sep.join(header)] + [sep.join(fmt % v for v in row) for row in data]
    path.write_text("\n".join(lines) + "\n")
    return path


def test_import_with_column_mapping_and_units(tmp_path, capsys):
    t, x, f, p = _signals()
    csv = _write_csv(tmp_path / "daq.csv", ["t_ms", "Stroke", "Load", "P_muscle"],
                     [t * 1e3, x * 1e-3, f * 1e-3, p * 1e3])
    out = tmp_path / "daq.h5"
    rc = main(["import", str(csv), "--out", str(out), "--time-col", "t_ms", "--position-col",
               "stroke", "--force-col", "Load", "--pressure-col", "P_muscle", "--units",
               "time=ms,position=m,force=kN,pressure=kPa", "--run", "bench-1"])
    assert rc == 0
    assert "bench-1" in capsys.readouterr().out
    (r,) = read_runs(out)
    assert r.name == "bench-1"
    np.testing.assert_allclose(r.time, t, atol=1e-9)
    np.testing.assert_allclose(r.position, x, rtol=1e-7)
    np.testing.assert_allclose(r.force, f, rtol=1e-7)
    np.testing.assert_allclose(r.muscle_pressure, p, rtol=1e-7)
    assert r.attrs["muscle_pressure_MPa"] == pytest.approx(0.45)
    assert r.attrs["sample_rate_Hz"] == pytest.approx(500.0)
    assert r.cylinder_pressure is None


def test_import_defaults_constant_pressure_and_negate(tmp_path):
    t, x, f, _ = _signals()
    csv = _write_csv(tmp_path / "d.csv", ["time", "position", "force"], [t, -x, f], sep=";")
    opts = CsvImportOptions(pressure_MPa=0.3, delimiter=";", negate=("position",))
    r = read_csv_run(csv, opts)
    np.testing.assert_allclose(r.position, x)
    assert np.all(r.muscle_pressure == 0.3) and r.nominal_pressure == 0.3
    assert r.name == "d"


@pytest.mark.parametrize(
    "header, cols, args, needle",
    [
        (["time", "position", "force"], None, ["--pressure", "0.4", "--force-col", "Fz"],
         "channel 'force': no column 'Fz' (columns: time, position, force)"),
        (["time", "position", "force"], None, [],
         "channel 'muscle_pressure': no column 'muscle_pressure'"),
        (["time", "position", "force"], None, ["--pressure", "0.4", "--units", "force=lbf"],
         "--units: unknown unit 'lbf' for force"),
        (["time", "position", "force"], None, ["--pressure", "0.4", "--units", "torque=Nm"],
         "unknown quantity 'torque'"),
        (["time", "position", "force"], "reversed", ["--pressure", "0.4"],
         "channel 'time': time not strictly increasing"),
        (["time", "position", "force"], "text", ["--pressure", "0.4"],
         "channel 'position': column 'position' row 5 is not a number ('abc')"),
    ],
)
def test_bad_csv_is_one_line(tmp_path, capsys, header, cols, args, needle):
    t, x, f, _ = _signals()
    csv = tmp_path / "bad.csv"
    if cols == "reversed":
        t = t[::-1]
    _write_csv(csv, header, [t, x, f])
    if cols == "text":
        lines = csv.read_text().splitlines()
        parts = lines[4].split(",")
        parts[1] = "abc"
        lines[4] = ",".join(parts)
        csv.write_text("\n".join(lines) + "\n")
    rc = main(["import", str(csv), "--out", str(tmp_path / "o.h5"), *args])
    err = capsys.readouterr().err.strip()
    assert rc != 0 and err.count("\n") == 0, err
    assert needle in err, err
    assert not (tmp_path / "o.h5").exists()


def test_not_a_csv_and_missing_file(tmp_path):
    bad = tmp_path / "x.csv"
    bad.write_bytes(b"\x00\xff\xfe binary \x00")
    with pytest.raises(RunFileError) as ei:
        read_csv_run(bad, CsvImportOptions(pressure_MPa=0.3))
    assert str(ei.value).startswith(str(bad)) and "\n" not in str(ei.value)
    with pytest.raises(RunFileError, match="no such file"):
        read_csv_run(tmp_path / "nope.csv", CsvImportOptions())


def test_import_refuses_overwrite_without_force(tmp_path, capsys):
    t, x, f, p = _signals()
    csv = _write_csv(tmp_path / "a.csv", ["time", "position", "force", "muscle_pressure"],
                     [t, x, f, p])
    out = tmp_path / "a.h5"
    out.write_bytes(b"keep")
    assert main(["import", str(csv), "--out", str(out)]) != 0
    assert "already exists" in capsys.readouterr().err and out.read_bytes() == b"keep"
    assert main(["import", str(csv), "--out", str(out), "--force"]) == 0
    assert len(read_runs(out)[0]) == N


def test_parse_units_maps_pressure_to_all_pressure_channels():
    u = parse_units("pressure=bar, position=um")
    assert u == {"muscle_pressure": "bar", "cylinder_pressure": "bar",
                 "cylinder_pressure_command": "bar", "position": "um"}
    with pytest.raises(RunFileError, match="not KEY=UNIT"):
        parse_units("position")
