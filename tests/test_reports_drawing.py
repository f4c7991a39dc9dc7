"""How a report page is drawn: laid out once (as saving to PDF lays it out), then drawn
once per export; the PDF page and its PNG are those of a plain ``savefig``."""

from __future__ import annotations

import io
import re

import matplotlib as mpl
import numpy as np
import pytest
from matplotlib.backends.backend_pdf import PdfPages
from matplotlib.figure import Figure
from PIL import Image

from pmalab.reports import style
from pmalab.reports.pdf import PageSpec, write_pdf


@style.styled
def _page(title: str) -> Figure:
    """A small constrained-layout page with a colour bar (an axes locator) and long labels."""
    fig = style.new_figure(title)
    left, right = fig.subplots(1, 2)
    x = np.linspace(0.0, 20.0, 50)
    left.plot(x, 300.0 - 9.0 * x, label="measured")
    left.set(xlabel=style.POSITION, ylabel=style.FORCE, title="a loop")
    left.legend()
    im = right.imshow(np.outer(x, x), aspect="auto", cmap=style.ERROR_CMAP)
    fig.colorbar(im, ax=right, label=style.ABS_ERROR)
    right.set(xlabel=style.TIME, ylabel=style.PRESSURE)
    return fig


def _pdf_bytes(fig: Figure) -> bytes:
    buf = io.BytesIO()
    with mpl.rc_context(style.RC), PdfPages(buf) as pdf:
        pdf.savefig(fig)
    return re.sub(rb"/CreationDate \(.*?\)", b"", buf.getvalue())


def test_laid_out_page_saves_as_a_plain_savefig_does():
    """style.lay_out then savefig gives the very PDF (byte for byte) a plain savefig of the
    constrained-layout page gives, and the PNG exported afterwards keeps that layout."""
    plain, laid = _page("A page"), _page("A page")
    want = _pdf_bytes(plain)
    with mpl.rc_context(style.RC):
        style.lay_out(laid)
    assert laid.get_layout_engine() is None
    assert _pdf_bytes(laid) == want
    np.testing.assert_allclose(  # the colour bar too, once its locator has placed it
        [ax.get_position().bounds for ax in laid.axes],
        [ax.get_position().bounds for ax in plain.axes],
        atol=1e-12,
    )
    # the plain page, kept as it was saved, exports the same PNG as the laid-out one
    style.keep_layout(plain)
    pngs = []
    for fig in (plain, laid):
        buf = io.BytesIO()
        with mpl.rc_context(style.RC):
            fig.savefig(buf, format="png", dpi=60)
        pngs.append(np.asarray(Image.open(buf)))
    assert np.array_equal(*pngs)


def test_each_page_is_drawn_once_per_export(tmp_path):
    """A report page with a PNG export costs two draws (PDF, PNG): no draw without output
    to run the layout engine, none for a placeholder engine."""
    draws: list[str] = []

    def make(title: str):
        def page(i: int, n: int) -> Figure:
            fig = _page(title)
            fig.canvas.mpl_connect("draw_event", lambda e: draws.append(title))
            return fig

        return page

    pages = [PageSpec(f"p{k}", f"page {k}", make(f"page {k}")) for k in (1, 2)]
    out = write_pdf(tmp_path / "r.pdf", pages, title="t", png_dir=tmp_path / "png")
    assert out.exists() and len(list((tmp_path / "png").glob("*.png"))) == 2
    assert draws == ["page 1", "page 1", "page 2", "page 2"]


@style.styled
def _offset_page() -> Figure:
    """A page whose y tick labels need an offset text (×1e-7) right under a long title."""
    fig = style.new_figure("Offsets")
    ax = fig.subplots()
    ax.plot([0.0, 1.0], [1.0e-7, 3.0e-7])
    ax.set_title("a title as wide as the axes, left aligned over the offset text", loc="left")
    return fig


def test_titles_are_placed_once_where_a_draw_places_them():
    """A title raised above the y offset text by matplotlib's draw is raised just as far on
    the laid-out page, and its place is kept for every export (no draw moves it)."""
    plain, laid = _offset_page(), _offset_page()
    pdf = _pdf_bytes(plain)
    want = plain.axes[0]._left_title.get_position()
    assert want[1] > 1.0  # raised: the test page does need it
    with mpl.rc_context(style.RC):
        style.lay_out(laid)
    got = laid.axes[0]._left_title.get_position()
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-9)
    # laid out again with the raised title in every pass: matplotlib's own page
    assert _pdf_bytes(laid) == pdf
    laid.savefig(io.BytesIO(), format="png", dpi=60)
    assert laid.axes[0]._left_title.get_position() == got


def test_png_export_is_matplotlibs_pixels_rgb_when_opaque(tmp_path):
    """save_figure's PNG holds the very pixels matplotlib's own PNG writer gives (same rc),
    as RGB for an opaque page, RGBA for a figure with transparent parts."""
    fig = _page("A page")
    with mpl.rc_context(style.RC):
        style.lay_out(fig)
        fig.savefig(tmp_path / "mpl.png", dpi=50)
    ours = style.save_figure(fig, tmp_path / "ours.png", dpi=50)
    want = np.asarray(Image.open(tmp_path / "mpl.png"))
    with Image.open(ours) as img:
        assert img.mode == "RGB" and img.info["dpi"] == pytest.approx((50, 50), abs=0.02)
        got = np.asarray(img)
    assert (want[..., 3] == 255).all() and np.array_equal(got, want[..., :3])
    clear = Figure(figsize=(2, 1))
    clear.patch.set_alpha(0.0)
    clear.text(0.5, 0.5, "x")
    with Image.open(style.save_figure(clear, tmp_path / "clear.png", dpi=40)) as img:
        assert img.mode == "RGBA" and np.asarray(img)[0, 0, 3] == 0


def test_without_matplotlibs_title_placement_every_draw_places_the_titles(monkeypatch):
    """The title placement lay_out relies on is matplotlib's private API
    (``_autotitlepos``, ``_update_title_position``).  An axes without it is left out
    (``_auto_titled``), and a page whose axes are all left out is laid out and drawn as a
    plain savefig draws it: the title raised over the offset text by each draw, the PDF
    the same byte for byte."""
    from types import SimpleNamespace

    no_api = SimpleNamespace(title=SimpleNamespace(get_text=lambda: "t"))  # neither attribute
    no_placer = SimpleNamespace(title=no_api.title, _autotitlepos=None)
    no_flag = SimpleNamespace(title=no_api.title, _update_title_position=lambda r: None)
    fake = SimpleNamespace(axes=[no_api, no_placer, no_flag])
    assert style._auto_titled(fake) == []  # pyright: ignore[reportArgumentType]

    plain, laid = _offset_page(), _offset_page()
    pdf = _pdf_bytes(plain)
    monkeypatch.setattr(style, "_auto_titled", lambda fig: [])
    with mpl.rc_context(style.RC):
        style.lay_out(laid)
    assert laid.get_layout_engine() is None
    assert laid.axes[0]._autotitlepos is not False  # left to matplotlib: placed on each draw
    assert _pdf_bytes(laid) == pdf
    assert laid.axes[0]._left_title.get_position()[1] > 1.0


def test_png_export_takes_savefigs_pil_kwargs(tmp_path):
    """Pillow options given to savefig (dpi, compression) override the export's own, as with
    matplotlib's PNG writer, instead of failing on a keyword given twice."""
    fig = Figure(figsize=(2, 1))
    fig.text(0.5, 0.5, "x")
    style._PngCanvas(fig)
    fig.savefig(tmp_path / "a.png", dpi=40, pil_kwargs={"dpi": (72, 72), "compress_level": 9})
    with Image.open(tmp_path / "a.png") as img:
        assert img.info["dpi"] == pytest.approx((72, 72), abs=0.02) and img.size == (80, 40)


def test_laid_out_ticks_are_fixed_and_drawn_as_their_locators_place_them():
    """After lay_out the ticks of a page are fixed where its locators and formatters put
    them (with the formatter's offset text): the PDF and PNG draws run no locator, and draw
    the very PDF and pixels a page with its locators running gives."""
    calls: list[int] = []

    class Counting(mpl.ticker.MaxNLocator):
        def __call__(self):
            calls.append(1)
            return super().__call__()

    def page() -> Figure:
        fig = _offset_page()
        fig.axes[0].xaxis.set_major_locator(Counting(nbins=5))
        return fig

    plain, laid = page(), page()
    pdf = _pdf_bytes(plain)
    with mpl.rc_context(style.RC):
        style.lay_out(laid)
    axis = laid.axes[0].yaxis
    assert isinstance(axis.get_major_locator(), mpl.ticker.FixedLocator)
    assert axis.get_major_formatter().get_offset() == plain.axes[0].yaxis.get_major_formatter().get_offset() != ""
    calls.clear()
    assert _pdf_bytes(laid) == pdf
    style.keep_layout(plain)
    pngs = []
    for fig in (plain, laid):
        buf = io.BytesIO()
        with mpl.rc_context(style.RC):
            fig.savefig(buf, format="png", dpi=60)
        pngs.append(np.asarray(Image.open(buf)))
    assert np.array_equal(*pngs)
    assert len(calls) >= 1  # the plain page's PNG draw ran its locator
    n_plain = len(calls)
    calls.clear()
    laid.savefig(io.BytesIO(), format="png", dpi=60)
    assert calls == [] and n_plain > 0


def test_pdf_draw_measures_no_text_the_layout_measured(monkeypatch):
    """save_pdf_page draws a laid-out page with the text metrics its layout measured (the
    PDF backend's, at 72 dpi): no text is measured twice, and the PDF is the same bytes."""
    from matplotlib.backends.backend_pdf import RendererPdf

    measured: list[str] = []
    real = RendererPdf.get_text_width_height_descent

    def count(self, s, prop, ismath):
        measured.append(s)
        return real(self, s, prop, ismath)

    plain, laid = _page("A page"), _page("A page")
    want = _pdf_bytes(plain)
    monkeypatch.setattr(RendererPdf, "get_text_width_height_descent", count)
    with mpl.rc_context(style.RC):
        style.lay_out(laid)
    in_layout = set(measured)
    assert in_layout
    measured.clear()
    buf = io.BytesIO()
    with mpl.rc_context(style.RC), PdfPages(buf) as pdf:
        style.save_pdf_page(pdf, laid)
    assert not in_layout & set(measured)
    assert re.sub(rb"/CreationDate \(.*?\)", b"", buf.getvalue()) == want


def test_png_text_drawn_from_kept_glyph_layouts_is_aggs_own(tmp_path):
    """A PNG page whose texts repeat (tick labels on many axes, rotated, bold, math) is
    drawn from glyph layouts kept per font, size, dpi and text: fewer layouts than texts
    drawn, the very pixels matplotlib's Agg gives."""
    with mpl.rc_context(style.RC):
        fig = style.new_figure("Repeated labels $\\alpha$")
        for ax in fig.subplots(2, 3).ravel():
            ax.plot([0.0, 10.0], [0.0, 5.0])
            ax.set_xlabel("Time t (s)")
            ax.set_ylabel(r"$F_{model}$ (N)")
            ax.text(5.0, 2.0, "rotated", rotation=33, fontweight="bold")
        style.lay_out(fig)
        fig.savefig(tmp_path / "mpl.png", dpi=70)
    style._GLYPH_LAYOUTS.clear()
    ours = style.save_figure(fig, tmp_path / "ours.png", dpi=70)
    want = np.asarray(Image.open(tmp_path / "mpl.png"))[..., :3]
    assert np.array_equal(np.asarray(Image.open(ours)), want)
    texts = sum(1 for t in fig.findobj(mpl.text.Text) if t.get_text() and t.get_visible())
    assert 0 < len(style._GLYPH_LAYOUTS) < texts / 2
