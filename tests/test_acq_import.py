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


# --------------------------------------------------------------------------- real exports
LABVIEW_HEADER = """LabVIEW Measurement\t
Writer_Version\t2
Reader_Version\t2
Separator\tTab
Decimal_Separator\t.
Multi_Headings\tNo
X_Columns\tOne
Time_Pref\tRelative
Operator\tbench 3
Date\t2024/03/05
Time\t14:21:07.1230
***End_of_Header***\t

"""


def _labview(path):
    """A LabVIEW-style text export: a metadata block, tab-separated, units in the names."""
    t, x, f, p = _signals()
    rows = "\n".join(f"{a:.6f}\t{b:.6f}\t{c:.5f}\t{d * 1e3:.4f}\t" for a, b, c, d in
                     zip(t, x, f, p))
    path.write_text(LABVIEW_HEADER + "Time (s)\tStroke (mm)\tLoad (N)\tP_muscle (kPa)\t\n"
                    + rows + "\n")
    return path


def _dewesoft(path):
    """A DEWESoft-style export: ';' with decimal comma, a units row, cp1252 text (µ)."""
    t, x, f, p = _signals()
    lines = ["Zeit;Weg;Kraft;Druck", "[s];[µm];[kN];[bar]"]
    for a, b, c, d in zip(t, x, f, p):
        lines.append(";".join(f"{v:.7f}".replace(".", ",") for v in (a, b * 1e3, c / 1e3,
                                                                     d * 10)))
    path.write_bytes(("\r\n".join(lines) + "\r\n").encode("cp1252"))
    return path


def _check_signals(r):
    t, x, f, p = _signals()
    np.testing.assert_allclose(r.time, t, atol=1e-6)
    np.testing.assert_allclose(r.position, x, atol=1e-6)
    np.testing.assert_allclose(r.force, f, atol=1e-4)
    np.testing.assert_allclose(r.muscle_pressure, p, atol=1e-6)


def test_import_a_labview_style_export(tmp_path, capsys):
    src = _labview(tmp_path / "lv.lvm")
    out = tmp_path / "lv.h5"
    rc = main(["import", str(src), "--out", str(out), "--header-rows", "13", "--delimiter",
               "\\t", "--time-col", "Time", "--position-col", "stroke", "--force-col", "Load",
               "--pressure-col", "P_muscle"])
    assert rc == 0, capsys.readouterr().err
    (r,) = read_runs(out)
    _check_signals(r)  # units came from the names: (s), (mm), (N), (kPa)


def test_import_a_dewesoft_style_export(tmp_path, capsys):
    src = _dewesoft(tmp_path / "dw.csv")
    out = tmp_path / "dw.h5"
    rc = main(["import", str(src), "--out", str(out), "--delimiter", ";", "--decimal", ",",
               "--encoding", "cp1252", "--units-row", "--time-col", "Zeit", "--position-col",
               "Weg", "--force-col", "Kraft", "--pressure-col", "Druck"])
    assert rc == 0, capsys.readouterr().err
    (r,) = read_runs(out)
    _check_signals(r)  # [µm] in cp1252, [kN], [bar] from the units row


def test_units_option_overrides_the_units_row(tmp_path):
    src = _dewesoft(tmp_path / "dw.csv")
    lines = src.read_bytes().decode("cp1252").splitlines()
    lines[1] = "[s];[um];[N];[bar]"  # a wrong force unit in the file
    src.write_bytes("\n".join(lines).encode("cp1252"))
    opts = CsvImportOptions(delimiter=";", decimal=",", units_row=True,
                            columns={"time": "Zeit", "position": "Weg", "force": "Kraft",
                                     "muscle_pressure": "Druck"},
                            units=parse_units("force=kN"))
    _check_signals(read_csv_run(src, opts))


EXPORT_MISTAKES = [
    # (writer, extra args, text the one line must hold)
    (_dewesoft, ["--delimiter", ";", "--decimal", ",", "--units-row"],
     "line 2: not utf-8 text (byte 0xb5); give --encoding (cp1252 for most Windows exports)"),
    (_dewesoft, ["--delimiter", ";", "--decimal", ",", "--encoding", "cp1252"],
     "column 'Zeit' row 2 is not a number ('[s]'): a units row? use --units-row"),
    (_dewesoft, ["--delimiter", ";", "--encoding", "cp1252", "--units-row"],
     "column 'Zeit' row 3 is not a number ('0,0000000'): a decimal comma? use --decimal ,"),
    (_dewesoft, ["--delimiter", ";", "--decimal", ",", "--encoding", "cp1252", "--units-row",
                 "--units", "position=mm"],
     "channel 'position': reaches 2e+04 mm at sample "),
    (_labview, ["--delimiter", "\\t"],
     "no column 'Time' (columns: LabVIEW Measurement); the names look like line 14: use "
     "--header-rows 13"),
    (_labview, ["--delimiter", "\\t", "--header-rows", "999"],
     "--header-rows 999: the file has only 414 line(s)"),
    (_labview, ["--delimiter", "\\t", "--header-rows", "13", "--units-row"],
     "channel 'time': unknown unit '0.000000' (expected one of s, ms)"),
    (_labview, ["--delimiter", "\\t", "--header-rows", "13", "--decimal", ";"],
     "--decimal: invalid choice"),
    (_labview, ["--delimiter", "ab"], "--delimiter: 'ab' is not one character"),
    (_labview, ["--delimiter", ",", "--decimal", ","], "--decimal ,: the same character as"),
    (_labview, ["--encoding", "klingon"], "--encoding: unknown encoding 'klingon'"),
]


@pytest.mark.parametrize("writer, args, needle", EXPORT_MISTAKES,
                         ids=[f"{i}" for i in range(len(EXPORT_MISTAKES))])
def test_export_mistakes_are_one_line_that_says_which_option(tmp_path, capsys, writer, args,
                                                            needle):
    src = writer(tmp_path / "x.csv")
    cols = (["--time-col", "Zeit", "--position-col", "Weg", "--force-col", "Kraft",
             "--pressure-col", "Druck"] if writer is _dewesoft else
            ["--time-col", "Time", "--position-col", "Stroke", "--force-col", "Load",
             "--pressure-col", "P_muscle"])
    rc = main(["import", str(src), "--out", str(tmp_path / "o.h5"), *cols, *args])
    err = capsys.readouterr().err.strip()
    assert rc != 0 and err.count("\n") == 0
    assert needle in err, err
    assert not (tmp_path / "o.h5").exists()


def test_a_kpa_csv_without_units_is_refused_naming_kpa(tmp_path, capsys):
    t, x, f, p = _signals()
    csv = _write_csv(tmp_path / "k.csv", ["time", "position", "force", "muscle_pressure"],
                     [t, x, f, p * 1e3])
    rc = main(["import", str(csv), "--out", str(tmp_path / "k.h5")])
    err = capsys.readouterr().err
    assert rc == 2 and err.count("\n") == 1
    assert ("k.csv: run 'k': channel 'muscle_pressure': reaches 450 MPa at sample 0, which no "
            "PMA test produces (gauge pressure between -0.05 and 1.2 MPa) — looks like kPa: use "
            "--units muscle_pressure=kPa") in err
    assert main(["import", str(csv), "--out", str(tmp_path / "k.h5"), "--units",
                 "muscle_pressure=kPa"]) == 0


def test_a_constant_pressure_beyond_any_pma_is_refused(tmp_path):
    t, x, f, _ = _signals()
    csv = _write_csv(tmp_path / "d.csv", ["time", "position", "force"], [t, x, f])
    with pytest.raises(RunFileError, match=r"--pressure: must be a muscle pressure > 0 and ≤ 1\.2"):
        read_csv_run(csv, CsvImportOptions(pressure_MPa=400.0))
