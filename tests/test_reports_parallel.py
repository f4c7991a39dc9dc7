"""Report pages rendered in worker processes: the joined PDF shows exactly what the
one-process PDF shows (page for page: text and pixels), under every start method."""

from __future__ import annotations

import numpy as np
import pytest
import reports_fixtures as rf
from pdf_pages import pdf_pages

from pmalab.reports import ReportError, build_report
from pmalab.reports.parallel import join_pdfs

pdfium = pytest.importorskip("pypdfium2")


@pytest.fixture(scope="module")
def serial(tmp_path_factory):
    d = rf.write_full_dir(tmp_path_factory.mktemp("par") / "res")
    return d, build_report(d, d.parent / "serial.pdf", jobs=1)


@pytest.mark.parametrize("method", ["spawn", "forkserver"])
def test_parallel_pages_equal_serial_pages(serial, tmp_path, method):
    d, one = serial
    png = tmp_path / "png"
    lines: list[str] = []
    two = build_report(
        d, tmp_path / "par.pdf", jobs=2, start_method=method, png_dir=png, progress=lines.append
    )
    a, b = pdf_pages(one), pdf_pages(two)
    assert len(a) == len(b) > 5
    for i, ((ta, ia), (tb, ib)) in enumerate(zip(a, b, strict=True), 1):
        assert ta == tb, f"page {i}: text differs"
        assert ia.shape == ib.shape and np.array_equal(ia, ib), f"page {i}: pixels differ"
    # progress lines in page order, one PNG per page, no scratch files left beside the PDF
    assert [ln.split(":")[0] for ln in lines] == [
        f"page {i}/{len(a)}" for i in range(1, len(a) + 1)
    ]
    assert len(list(png.glob("*.png"))) == len(a)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["par.pdf", "png"]
    meta = pdfium.PdfDocument(str(two)).get_metadata_dict()
    assert meta["Title"].startswith("pmalab report:") and meta["Creator"].startswith("pmalab")


def test_join_refuses_a_file_that_is_not_a_pdf(tmp_path):
    bad = tmp_path / "x.pdf"
    bad.write_bytes(b"not a pdf")
    with pytest.raises(ReportError, match=r"x\.pdf: not a complete PDF"):
        join_pdfs([bad], tmp_path / "out.pdf", {"Title": "t"})
