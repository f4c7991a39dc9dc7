"""Layout check of a drawn report page: no two texts overlap, no text leaves the page.

:func:`text_problems` draws the figure and compares the extents of every visible,
non-empty text (titles, labels, tick labels actually drawn, legend entries, table cells,
annotations).  Rotated texts are compared as rotated rectangles, so two slanted tick
labels that merely share a bounding box are not reported.  The report's tests run it on
every page as the PDF lays it out (:func:`page_problems`); ``python -m
pmalab.reports.layout DIR...`` checks a real result directory.
"""

from __future__ import annotations

import math
import sys
from collections.abc import Iterator

import matplotlib as mpl
import numpy as np
from matplotlib.axes import Axes
from matplotlib.axis import Axis
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.table import Cell
from matplotlib.text import Text

from pmalab.reports import style

#: overlaps smaller than this (display pixels at 100 dpi) are ignored: glyph boxes include
#: a little padding, and two texts that touch are still readable
TOLERANCE_PX = 1.0


def _drawn_ticks(axis: Axis) -> list:
    """The ticks the axis drew at the last draw (those inside the view interval)."""
    try:
        # the ticks to draw (matplotlib ≥ 3.x; private, hence the guard below)
        return list(axis._update_ticks())  # pyright: ignore[reportAttributeAccessIssue]
    except AttributeError:  # pragma: no cover - a future matplotlib
        return list(axis.get_major_ticks())


def _walk(artist) -> Iterator[Text]:
    """Visible texts below ``artist``, descending only into visible containers; an axis
    gives its label, offset text and the labels of the ticks it drew."""
    if not artist.get_visible():
        return
    if isinstance(artist, Axis):
        yield from (t for t in (artist.label, artist.offsetText) if t.get_visible())
        for tick in _drawn_ticks(artist):
            if tick.get_visible():
                yield from (lb for lb in (tick.label1, tick.label2) if lb.get_visible())
        return
    if isinstance(artist, Text):
        yield artist
    if isinstance(artist, Cell):  # a table cell's text is not among its children
        yield artist.get_text()
    off = isinstance(artist, Axes) and not artist.axison  # ax.axis("off"): no axis drawn
    for child in artist.get_children():
        if off and isinstance(child, Axis):
            continue
        yield from _walk(child)


def page_texts(fig: Figure) -> Iterator[Text]:
    """Every drawn, visible, non-empty text of ``fig`` (tick labels only for drawn ticks)."""
    seen: set[int] = set()
    for t in _walk(fig):
        if id(t) in seen or not t.get_text().strip() or t.get_alpha() == 0:
            continue
        seen.add(id(t))
        yield t


def _corners(t: Text, renderer) -> np.ndarray:
    """The text's rectangle (4 × 2 display coordinates), rotated with the text."""
    box = t.get_window_extent(renderer)
    rot = math.radians(t.get_rotation() % 360.0)
    if abs(math.sin(rot)) < 1e-6 or abs(math.cos(rot)) < 1e-6:
        return np.array([[box.x0, box.y0], [box.x1, box.y0], [box.x1, box.y1], [box.x0, box.y1]])
    # unrotated size: the text's layout without rotation (same font and string)
    old = t.get_rotation()
    t.set_rotation(0.0)
    try:
        flat = t.get_window_extent(renderer)
    finally:
        t.set_rotation(old)
    w, h = flat.width, flat.height
    cx, cy = (box.x0 + box.x1) / 2.0, (box.y0 + box.y1) / 2.0  # a rotated box's centre
    c, s = math.cos(rot), math.sin(rot)
    pts = np.array([[-w / 2, -h / 2], [w / 2, -h / 2], [w / 2, h / 2], [-w / 2, h / 2]])
    return pts @ np.array([[c, s], [-s, c]]) + [cx, cy]


def _overlap(a: np.ndarray, b: np.ndarray, tol: float) -> bool:
    """Separating-axis test of two convex quadrilaterals, shrunk by ``tol`` pixels."""
    for poly in (a, b):
        for i in range(4):
            edge = poly[(i + 1) % 4] - poly[i]
            n = np.array([-edge[1], edge[0]])
            norm = float(np.hypot(*n))
            if norm == 0.0:
                continue
            n /= norm
            pa, pb = a @ n, b @ n
            if pa.max() - tol <= pb.min() or pb.max() - tol <= pa.min():
                return False
    return True


def _owner(t: Text):
    """The axes a text belongs to (None: the figure's own text)."""
    return t.axes


def _related(ax) -> list:
    """Axes drawn as one with ``ax``: its colour bar's parent, twins, insets."""
    if ax is None:
        return []
    out = list(ax.child_axes)
    parent = getattr(ax, "_colorbar_parent", None)
    if parent is not None:
        out.append(parent)
    return out


def _axes_name(ax) -> str:
    title = " ".join(ax.get_title().split())
    if ax.get_label() == "<colorbar>":
        return "a colour bar"
    return repr(title[:30]) if title else "an axes"


def _name(t: Text) -> str:
    s = " ".join(t.get_text().split())
    return repr(s if len(s) <= 40 else s[:37] + "…")


def text_problems(fig: Figure, *, dpi: float = 100.0, tol: float = TOLERANCE_PX) -> list[str]:
    """Texts of ``fig`` that overlap each other or leave the page, one line each (empty
    when the page is clean).  Lays the figure out and places its texts first, as a draw at
    ``dpi`` does, without rasterizing it (the extents are those of a drawn page)."""
    fig.set_dpi(dpi)
    canvas = fig.canvas if isinstance(fig.canvas, FigureCanvasAgg) else FigureCanvasAgg(fig)
    fig.draw_without_rendering()  # with the canvas's renderer, the one read below
    renderer = canvas.get_renderer()
    texts = list(page_texts(fig))
    boxes = [_corners(t, renderer) for t in texts]
    W, H = fig.bbox.width, fig.bbox.height
    out = []
    for t, c in zip(texts, boxes):
        if (
            c[:, 0].min() < -tol
            or c[:, 1].min() < -tol
            or c[:, 0].max() > W + tol
            or c[:, 1].max() > H + tol
        ):
            out.append(f"{_name(t)} leaves the page")
    # the plot areas of drawn axes (colour bars included): a text of another axes (or of
    # the figure) must not run into them, as a long title into the next column's colour bar
    areas = [
        (ax, ax.patch.get_window_extent(renderer))
        for ax in fig.axes
        if ax.get_visible() and ax.axison
    ]
    for t, c in zip(texts, boxes):
        own = _owner(t)
        for ax, area in areas:
            if ax is own or ax in _related(own):
                continue
            quad = np.array(
                [[area.x0, area.y0], [area.x1, area.y0], [area.x1, area.y1], [area.x0, area.y1]]
            )
            if _overlap(c, quad, tol):
                out.append(f"{_name(t)} runs into the plot area of {_axes_name(ax)}")
    lo, hi = np.array([c.min(axis=0) for c in boxes]), np.array([c.max(axis=0) for c in boxes])
    for i in range(len(texts)):
        for j in range(i + 1, len(texts)):
            if (lo[i] >= hi[j] - tol).any() or (lo[j] >= hi[i] - tol).any():
                continue
            if _overlap(boxes[i], boxes[j], tol):
                out.append(f"{_name(texts[i])} overlaps {_name(texts[j])}")
    return out


def page_problems(fig: Figure, *, dpi: float = 150.0) -> list[str]:
    """:func:`text_problems` of a report page as the report writes it: laid out once before
    it is drawn into the PDF (:func:`pmalab.reports.style.lay_out`), that layout kept for
    its PNG/SVG export, checked at the export's ``dpi``."""
    # laid out as the report lays it out before saving it (the PDF backend's text metrics),
    # without writing the PDF: the same axes positions
    with mpl.rc_context(style.RC):
        style.lay_out(fig)
        return text_problems(fig, dpi=dpi)


def main(argv: list[str] | None = None) -> int:
    """``python -m pmalab.reports.layout DIR...``: check every page of the report of DIRs."""
    from pmalab.reports.build import draw_page, plan_pages
    from pmalab.reports.data import load_report_dir
    from pmalab.reports.errors import ReportError

    dirs = list(sys.argv[1:] if argv is None else argv)
    bad = 0
    try:
        data = load_report_dir(dirs)
    except ReportError as exc:  # a wrong directory: one line, no traceback
        print(f"python -m pmalab.reports.layout: error: {exc}", file=sys.stderr)
        return 2
    pages = plan_pages(data)
    for i, page in enumerate(pages, 1):
        probs = page_problems(draw_page(page, data, i, len(pages)))
        bad += bool(probs)
        for p in probs:
            print(f"page {i} ({page.title}): {p}")
    return 1 if bad else 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
