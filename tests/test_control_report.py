"""``pmalab report CONTROL.h5``: a metrics page, then response and gains pages per file."""

from __future__ import annotations

import contextlib
import io

import pypdfium2 as pdfium
import pytest
from pdf_pages import assert_same_pages

from pmalab.cli import main
from pmalab.reports.control import build_control_report


@pytest.fixture(scope="module")
def control_dir(tmp_path_factory):
    d = tmp_path_factory.mktemp("ctl")
    exp = d / "e.toml"
    exp.write_text('[experiments]\ncontrollers = ["pid", "sn-pid"]\nduration_s = 2.0\n'
                   '[[experiment]]\nname = "sq"\nreference = "square:0.5Hz:10mm"\n'
                   '[experiment.seeds]\nS1 = { classic_overshoot_pct = 31.0 }\n'
                   '[[experiment]]\nname = "p"\nreference = "square:0.5Hz:0.5MPa"\n')
    assert main(["control", "--experiments", str(exp), "--out", str(d / "out")]) == 0
    return d / "out"


@pytest.fixture(scope="module")
def control_report(control_dir, tmp_path_factory):
    """``pmalab report sq.h5 p.h5 --jobs 1``: its exit code, what it printed and the PDF
    (its pages drawn in the command's own process: the worker-processes test compares
    against it)."""
    out = tmp_path_factory.mktemp("ctl-report") / "r.pdf"
    printed = io.StringIO()
    with contextlib.redirect_stdout(printed):
        rc = main(["report", str(control_dir / "sq.h5"), str(control_dir / "p.h5"), "--out",
                   str(out), "--jobs", "1"])
    return rc, printed.getvalue(), out


def test_report_of_control_files_has_a_page_per_experiment_part(control_report):
    rc, printed, out = control_report
    assert rc == 0
    pdf = pdfium.PdfDocument(str(out))
    assert len(pdf) == 5  # metrics + (response, gains) × 2
    text = pdf[0].get_textpage().get_text_range()
    assert "sn-pid" in text and "classic overshoot 31 %" in text
    assert "report written" in printed


def test_control_files_and_result_directories_are_not_mixed(control_dir, tmp_path, capsys):
    rc = main(["report", str(control_dir / "sq.h5"), str(tmp_path), "--out",
               str(tmp_path / "r.pdf")])
    assert rc != 0
    assert "without result directories" in capsys.readouterr().err
    assert not (tmp_path / "r.pdf").exists()


def test_metrics_json_round_trips_through_its_typed_reader(control_dir, tmp_path):
    import json

    from pmalab.errors import PmalabError
    from pmalab.identify.schema import read_control_metrics

    path = control_dir / "metrics.json"
    doc = json.loads(path.read_text())
    assert read_control_metrics(path) == doc
    assert {r["controller"] for r in doc["results"]} == {"pid", "sn-pid"}
    # a damaged copy: one line naming the key path
    del doc["results"][1]["metrics"]["rms_error"]
    bad = tmp_path / "metrics.json"
    bad.write_text(json.dumps(doc))
    with pytest.raises(PmalabError) as e:
        read_control_metrics(bad)
    msg = str(e.value)
    assert "\n" not in msg and "results[1].metrics" in msg and "rms_error" in msg


def test_control_pages_rendered_in_worker_processes_equal_one_process(control_dir, control_report,
                                                                      tmp_path):
    files = [control_dir / "sq.h5", control_dir / "p.h5"]
    lines: list[str] = []
    one = control_report[2]  # the command's report, drawn in one process
    two = build_control_report(files, tmp_path / "two.pdf", jobs=2, start_method="spawn",
                               png_dir=tmp_path / "png", progress=lines.append)
    n = assert_same_pages(one, two, at_least=5)
    assert [ln.split(":")[0] for ln in lines] == [f"page {i}/{n}" for i in range(1, n + 1)]
    assert len(list((tmp_path / "png").glob("*.png"))) == n
    assert sorted(p.name for p in tmp_path.iterdir()) == ["png", "two.pdf"]  # nothing else
