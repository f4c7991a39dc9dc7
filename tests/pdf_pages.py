"""Comparing two PDFs page for page: the text and the rendered pixels of every page."""

from __future__ import annotations

from pathlib import Path

import numpy as np


def pdf_pages(pdf: Path) -> list[tuple[str, np.ndarray]]:
    """(text, RGB pixels at half scale) of every page of ``pdf``."""
    import pypdfium2 as pdfium

    doc = pdfium.PdfDocument(str(pdf))
    try:
        return [
            (
                doc[i].get_textpage().get_text_range(),
                np.asarray(doc[i].render(scale=0.5).to_pil().convert("RGB")),
            )
            for i in range(len(doc))
        ]
    finally:
        doc.close()


def assert_same_pages(one: Path, two: Path, *, at_least: int = 2) -> int:
    """Assert that ``one`` and ``two`` show the same pages (text and pixels, page for
    page) and hold at least ``at_least`` of them; return the page count."""
    a, b = pdf_pages(one), pdf_pages(two)
    assert len(a) == len(b) >= at_least, (len(a), len(b))
    for i, ((ta, ia), (tb, ib)) in enumerate(zip(a, b, strict=True), 1):
        assert ta == tb, f"page {i}: text differs"
        assert ia.shape == ib.shape and np.array_equal(ia, ib), f"page {i}: pixels differ"
    return len(a)
