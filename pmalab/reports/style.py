"""Page geometry, fonts, colours, labels and figure export shared by every report figure.

Pages are A4 landscape (297 × 210 mm) with fonts of at least 8 pt, so a page printed at
100 % is readable.  Figures are built with :class:`matplotlib.figure.Figure` directly (no
pyplot state), under :data:`RC` applied by the :func:`styled` decorator.
"""

from __future__ import annotations

import functools
import re
import textwrap
import weakref
from collections.abc import Callable
from pathlib import Path
from typing import Any, ParamSpec, TypeVar, cast

import matplotlib as mpl
import numpy as np
from matplotlib.axes import Axes
from matplotlib.backends.backend_agg import FigureCanvasAgg, RendererAgg, get_hinting_flag
from matplotlib.colors import LinearSegmentedColormap
from matplotlib.figure import Figure
from matplotlib.ft2font import FT2Font
from matplotlib.layout_engine import ConstrainedLayoutEngine, PlaceHolderLayoutEngine
from matplotlib.ticker import FixedFormatter, FixedLocator, NullLocator

from pmalab.paths import check_output
from pmalab.reports.errors import ReportError

A4_LANDSCAPE = (11.69, 8.27)  # inches
MIN_FONT_PT = 8.0

#: the report's rcParams (typed loosely: matplotlib types its keys as a literal list)
RC: dict[Any, Any] = {
    "font.size": 9.0,
    "axes.titlesize": 10.0,
    "axes.labelsize": 9.0,
    "xtick.labelsize": 8.0,
    "ytick.labelsize": 8.0,
    "legend.fontsize": 8.0,
    "figure.titlesize": 13.0,
    "axes.grid": True,
    "grid.alpha": 0.3,
    "grid.linewidth": 0.5,
    "lines.linewidth": 1.0,
    "axes.spines.top": False,
    "axes.spines.right": False,
    "svg.fonttype": "none",
    "pdf.fonttype": 3,
    # PNG text unhinted, as the PDF draws it and as the page was laid out (the PDF
    # backend's metrics): the same text widths in both exports, and a seventh less time
    # drawing a PNG page than FreeType's autohinter takes
    "text.hinting": "no_hinting",
}

# Colours: measured data is black, the model blue, errors on a dark-to-orange scale that
# stays visible on white at both ends.
MEASURED = "0.15"
#: the measured loop drawn as a wide band under a thinner model line
MEASURED_BAND = "0.62"
MODEL = "#1f77b4"
VALIDATION = "#d62728"
SIGNIFICANT = "#2ca02c"
NOT_SIGNIFICANT = "#9e9e9e"
ERROR_CMAP = LinearSegmentedColormap.from_list(
    "pmalab_error", mpl.colormaps["plasma"](np.linspace(0.0, 0.85, 256))
)

# Axis labels, units in parentheses (the sign convention of docs/explanation/physics.md).
TIME = "Time t (s)"
POSITION = "Contraction x (mm)"
FORCE = "Tension F (N)"
PRESSURE = "Muscle pressure p (MPa)"
RESIDUAL = "F − F_model (N)"
ABS_ERROR = "|F − F_model| (N)"

P = ParamSpec("P")
R = TypeVar("R")


def styled(fn: Callable[P, R]) -> Callable[P, R]:
    """Run a figure function under the report's rcParams."""

    @functools.wraps(fn)
    def wrapper(*args: P.args, **kwargs: P.kwargs) -> R:
        with mpl.rc_context(RC):
            return fn(*args, **kwargs)

    return wrapper


def new_figure(
    title: str | None = None, figsize: tuple[float, float] = A4_LANDSCAPE, *, layout: bool = True
) -> Figure:
    """An empty page-sized figure with an optional page title (call under :data:`RC`);
    ``layout=False`` for free-form pages placed in figure coordinates."""
    if not layout:
        fig = Figure(figsize=figsize)
        if title:
            fig.suptitle(title, fontweight="bold")
        return fig
    fig = Figure(figsize=figsize, layout="constrained")
    # rect leaves a strip at the bottom for the page footer
    engine = cast(ConstrainedLayoutEngine, fig.get_layout_engine())
    engine.set(w_pad=0.15, h_pad=0.12, hspace=0.06, wspace=0.05, rect=(0.0, 0.025, 1.0, 0.975))
    if title:
        fig.suptitle(title, fontweight="bold")
    return fig


def keep_layout(fig: Figure) -> None:
    """Fix ``fig``'s axes where its layout engine last placed them (a figure already drawn,
    e.g. into the PDF) and remove the engine, so that a further export of the same page
    (PNG, SVG) draws the very same layout at once instead of laying the page out again at
    another resolution: the constrained layout is a third of a page's drawing time.

    The engine is removed, not replaced by matplotlib's placeholder (``"none"``): with a
    placeholder, ``savefig`` still draws the whole page once without output before drawing
    it (a quarter of a PNG export's time, for nothing)."""
    if fig.get_layout_engine() is not None:
        with mpl.rc_context({"figure.autolayout": False, "figure.constrained_layout.use": False}):
            fig.set_layout_engine(None)


def lay_out(fig: Figure) -> None:
    """Lay ``fig`` out once as the PDF backend lays it out when the page is saved, and keep
    that layout (:func:`keep_layout`) for every export of the page (call under :data:`RC`).

    ``savefig`` of a figure with a layout engine draws the whole page twice: once without
    output, to run the engine, then for real.  This runs the engine alone, in the state
    that first draw gives it (the PDF backend's text metrics at 72 dpi, axes locators
    applied first), so the page's PDF and PNG exports are each drawn once, in the very
    layout a plain ``savefig`` to PDF gives.

    Axes titles are placed once, after the layout (:func:`_place_titles`).  While the
    engine runs they sit where a title sits unless something on top of its axes (top tick
    labels, an offset text) pushes it up; if one is pushed up at the end, the page is laid
    out again from where it started with the titles placed on every pass, as matplotlib
    does, so that their height is left free.

    The ticks are then fixed where the layout leaves them (:func:`_fix_ticks`) and the
    layout's text metrics kept for the PDF draw (:func:`save_pdf_page`): call it last,
    when nothing on the page changes any more.
    """
    engine = fig.get_layout_engine()
    if engine is None or isinstance(engine, PlaceHolderLayoutEngine) or not fig.axes:
        keep_layout(fig)
        return
    from matplotlib.backends.backend_pdf import FigureCanvasPdf

    canvas, dpi = fig.canvas, fig.dpi
    FigureCanvasPdf(fig)  # the canvas savefig(format="pdf") switches to
    try:
        # the PDF backend's renderer; getting it sets the figure's dpi to 72 pt per inch,
        # as saving does
        renderer = fig._get_renderer()  # pyright: ignore[reportAttributeAccessIssue]
        # the engine's passes measure with this renderer too (each would get a new one of
        # the same kind): one cache of text metrics for the layout, kept for the PDF draw
        fig._get_renderer = lambda: renderer  # pyright: ignore[reportAttributeAccessIssue]
        for ax in fig.axes:  # as Figure.draw does before it runs the engine
            for a in (ax, *ax.child_axes):
                locator = a.get_axes_locator()
                a.apply_aspect(locator(a, renderer) if locator else None)
        titled = _auto_titled(fig)
        start = _geometry(fig) if titled else []
        for ax in titled:  # titles at the top of their axes while the engine runs
            for t in _titles(ax):
                t.set_y(1.0)
            ax._autotitlepos = False
        engine.execute(fig)
        if _place_titles(titled, renderer):  # one pushed up: matplotlib's own layout
            _restore_geometry(start)
            for ax in titled:
                ax._autotitlepos = True
            engine.execute(fig)
            _place_titles(titled, renderer)
        _fix_ticks(fig, renderer)
        _keep_text_metrics(fig, renderer)
    finally:
        vars(fig).pop("_get_renderer", None)
        fig.set_dpi(dpi)
        fig.set_canvas(canvas)
    keep_layout(fig)


def _fix_ticks(fig: Figure, renderer: Any) -> None:
    """Fix the ticks of ``fig``'s laid-out axes where a draw would put them: each axis'
    locations and labels as its locator and formatter give them now (in the final layout,
    at the PDF's 72 dpi), kept as fixed ones with the formatter's offset text.  Every draw
    (PDF, PNG) and every tick-label extent otherwise runs the locators and formatters again
    (two to three times per axis per draw) for the same ticks.

    Only plain axes with free aspect are fixed (a draw changes nothing there that moves a
    tick); others keep their locators."""
    for ax in cast(list[Any], fig.axes):
        if ax.name != "rectilinear" or ax.get_aspect() != "auto" or not ax.get_visible():
            continue
        locator = ax.get_axes_locator()
        ax.apply_aspect(locator(ax, renderer) if locator else None)  # as a draw does first
        for axis in (ax.xaxis, ax.yaxis):
            for ticker in (axis.major, axis.minor):
                if isinstance(ticker.locator, NullLocator) or (
                    isinstance(ticker.locator, FixedLocator)
                    and isinstance(ticker.formatter, FixedFormatter)
                ):
                    continue
                locs = ticker.locator()
                labels = ticker.formatter.format_ticks(locs)
                fixed_formatter = FixedFormatter(labels)
                fixed_formatter.set_offset_string(ticker.formatter.get_offset())
                fixed_locator = FixedLocator(locs)
                fixed_locator.set_axis(axis)
                fixed_formatter.set_axis(axis)
                ticker.locator, ticker.formatter = fixed_locator, fixed_formatter


#: the attribute of a laid-out figure that keeps its layout's text metrics for its PDF draw
#: (the same PDF text metrics at the same 72 dpi): the layout renderer and its metrics cache
#: (on the figure, not in a weak mapping: the renderer refers to the figure)
_LAYOUT_METRICS = "_pmalab_layout_metrics"


def _keep_text_metrics(fig: Figure, renderer: Any) -> None:
    cache = _metrics_cache()
    if cache is not None and renderer in cache:
        vars(fig)[_LAYOUT_METRICS] = (renderer, cache[renderer])


def _metrics_cache() -> Any:
    """Matplotlib's per-renderer cache of text metrics (private: None if it has none)."""
    import matplotlib.text as mtext

    fn = getattr(mtext, "_get_text_metrics_function", None)
    defaults = getattr(fn, "__defaults__", None)
    cache = defaults[0] if defaults else None
    return cache if isinstance(cache, weakref.WeakKeyDictionary) else None


def save_pdf_page(pdf: Any, fig: Figure) -> None:
    """``pdf.savefig(fig)`` (a :class:`~matplotlib.backends.backend_pdf.PdfPages`) for a
    page laid out by :func:`lay_out`: the PDF draw measures its texts from the layout's
    text metrics (the same PDF backend's metrics at the same 72 dpi) instead of measuring
    each text again."""
    kept = vars(fig).pop(_LAYOUT_METRICS, None)
    cache = _metrics_cache()
    if kept is None or cache is None:
        pdf.savefig(fig)
        return
    layout_renderer, metrics = kept
    figure_draw = type(fig).draw

    def draw(renderer: Any) -> None:
        if type(renderer) is type(layout_renderer) and type(
            getattr(renderer, "_renderer", None)
        ) is type(getattr(layout_renderer, "_renderer", None)):
            cache[renderer] = metrics
        figure_draw(fig, renderer)

    fig.draw = draw  # pyright: ignore[reportAttributeAccessIssue]
    try:
        pdf.savefig(fig)
    finally:
        del fig.draw


def _titles(ax: Any) -> tuple[Any, Any, Any]:
    return ax.title, ax._left_title, ax._right_title


def _auto_titled(fig: Figure) -> list[Any]:
    """The axes of ``fig`` whose titles matplotlib places itself (its private placement;
    none under another matplotlib that lacks it: there, every draw places them)."""
    return [
        ax
        for ax in cast(list[Any], fig.axes)
        if getattr(ax, "_autotitlepos", False) is not False
        and hasattr(ax, "_update_title_position")
        and any(t.get_text() for t in _titles(ax))
    ]


def _place_titles(titled: list[Any], renderer: Any) -> bool:
    """Place the titles of the laid-out axes ``titled`` as a draw places them, and keep them
    there (otherwise every draw places them again, measuring the tick labels anew); True
    when one had to be pushed up above its axes' top."""
    pushed = False
    for ax in titled:
        locator = ax.get_axes_locator()
        ax.apply_aspect(locator(ax, renderer) if locator else None)
        ax._autotitlepos = True
        ax._update_title_position(renderer)
        ax._autotitlepos = False
        pushed |= any(t.get_position()[1] != 1.0 for t in _titles(ax))
    return pushed


def _geometry(fig: Figure) -> list[tuple[Any, Any, Any, Any, Any, Any]]:
    """Where every axes of ``fig`` is (original and active box, anchor, box aspect, aspect):
    what a layout engine changes."""
    return [
        (
            ax,
            ax.get_position(original=True).frozen(),
            ax.get_position(original=False).frozen(),
            ax.get_anchor(),
            ax.get_box_aspect(),
            ax.get_aspect(),
        )
        for ax in cast(list[Any], fig.axes)
    ]


def _restore_geometry(geometry: list[tuple[Any, Any, Any, Any, Any, Any]]) -> None:
    for ax, original, active, anchor, box_aspect, aspect in geometry:
        ax._set_position(original, which="original")  # in the layout still (set_position
        ax._set_position(active, which="active")  # would take the axes out of it)
        ax.set_anchor(anchor)
        ax.set_box_aspect(box_aspect)
        ax.set_aspect(aspect)


def grid_shape(n: int) -> tuple[int, int]:
    """Rows × columns for ``n`` panels on a landscape page (at most 2 × 3)."""
    if n <= 2:
        return 1, max(n, 1)
    if n <= 4:
        return 2, 2
    return 2, 3


def panel_axes(fig: Figure, n: int, nrows: int, ncols: int) -> list[Axes]:
    """An ``nrows × ncols`` grid on ``fig``; the first ``n`` axes, the unused cells hidden."""
    axes = list(fig.subplots(nrows, ncols, squeeze=False).ravel())
    for ax in axes[n:]:
        ax.set_visible(False)
    return axes[:n]


#: the units page text writes after a number, alone or compound (``N/mm``, ``N·s/mm``,
#: ``%/h``, ``mm/s``)
_UNIT = r"(?:N|mm|mm²|kPa|MPa|bar|Hz|s|ms|h|%|°C|x|×)"
#: a number and the unit after it (``-117 N``, ``2.5 Hz``, ``12 %``, ``4.2 N/mm``): one word
#: when wrapped
_NUMBER_UNIT = re.compile(rf"(?<=\d) (?={_UNIT}(?:[/·]{_UNIT})*(?![\w/·²]))")


def wrap(text: str, width: int, **kwargs: Any) -> list[str]:
    """``textwrap.wrap`` for page text: a number is never split from its unit (the space
    between them is a no-break space while the lines are cut, a plain space again after)."""
    lines = textwrap.wrap(_NUMBER_UNIT.sub("\u00a0", text), width, **kwargs)
    return [line.replace("\u00a0", " ") for line in lines]


def decimate(n: int, max_points: int) -> slice:
    """A stride that keeps at most ``max_points`` of ``n`` samples (for vector output)."""
    step = max(1, int(np.ceil(n / max_points))) if max_points > 0 else 1
    return slice(None, None, step)


def save_figure(fig: Figure, path: str | Path, *, force: bool = False, dpi: int = 200) -> Path:
    """Export one figure as PNG, SVG or PDF (by suffix); refuse to overwrite unless ``force``."""
    p = Path(path)
    fmt = p.suffix.lower().lstrip(".")
    if fmt not in ("png", "svg", "pdf"):
        raise ReportError(f"{p}: unsupported figure format '{p.suffix}' (use .png, .svg or .pdf)")
    check_output(p, force)
    p.parent.mkdir(parents=True, exist_ok=True)
    with mpl.rc_context(RC):
        if fmt == "png":
            _save_png(fig, p, dpi)
        else:
            fig.savefig(p, format=fmt, dpi=dpi)
    return p


#: zlib level of exported PNGs: level 3 writes an opaque report page in about half the time
#: of the default 6, and, as RGB, in fewer bytes than the default RGBA file
PNG_COMPRESS_LEVEL = 3


def _save_png(fig: Figure, p: Path, dpi: float) -> None:
    """Write ``fig`` as a PNG at ``dpi``: the pixels ``savefig`` draws (Agg), as RGB when the
    page is opaque (a report page always is), else RGBA, with savefig's metadata."""
    canvas = fig.canvas
    _PngCanvas(fig)
    try:
        fig.savefig(p, format="png", dpi=dpi)
    finally:
        fig.set_canvas(canvas)


#: glyph layouts of the texts drawn into PNG pages (by font, size, dpi, text, layout
#: options): a page draws the same tick labels on many axes, a report on many pages
_GLYPH_LAYOUTS: dict[tuple[Any, ...], tuple[Any, ...]] = {}
_GLYPH_LAYOUTS_MAX = 20_000


class _PngRenderer(RendererAgg):
    """Agg drawing a text as :meth:`RendererAgg.draw_text` does, from the glyph layout
    FreeType gave the same text in the same font, size and dpi before (the layout is a
    function of those alone) instead of laying the glyphs out again."""

    def draw_text(  # pyright: ignore[reportIncompatibleMethodOverride]
        self,
        gc: Any,
        x: float,
        y: float,
        s: str,
        prop: Any,
        angle: float,
        ismath: Any = False,
        mtext: Any = None,
    ) -> None:
        if ismath or not _GLYPH_REUSE:
            return super().draw_text(gc, x, y, s, prop, angle, ismath, mtext)
        font = self._prepare_font(prop)
        flags = get_hinting_flag()
        features = mtext.get_fontfeatures() if mtext is not None else None
        language = mtext.get_language() if mtext is not None else None
        size = prop.get_size_in_points()
        key = (font, size, self.dpi, s, flags, features, language)
        try:
            items = _GLYPH_LAYOUTS.get(key)
        except TypeError:  # unhashable layout options: as Agg draws it
            return super().draw_text(gc, x, y, s, prop, angle, ismath, mtext)
        if items is None:
            if len(_GLYPH_LAYOUTS) >= _GLYPH_LAYOUTS_MAX:
                _GLYPH_LAYOUTS.clear()
            items = tuple(font._layout(s, flags=flags, features=features, language=language))
            _GLYPH_LAYOUTS[key] = items
        self._draw_text_glyphs_and_boxes(
            gc,
            x,
            y,
            angle,
            ((item.ft_object, size, item.glyph_index, 0, 1, item.x, item.y) for item in items),
            [],
        )


#: the matplotlib internals :class:`_PngRenderer` draws with (matplotlib ≥ 3.11)
_GLYPH_REUSE = hasattr(RendererAgg, "_draw_text_glyphs_and_boxes") and hasattr(FT2Font, "_layout")


class _PngCanvas(FigureCanvasAgg):
    """Agg, writing its PNG as RGB when every pixel is opaque, at :data:`PNG_COMPRESS_LEVEL`."""

    def get_renderer(self) -> RendererAgg:
        """Agg's renderer (:class:`_PngRenderer`), new when the size or dpi change."""
        w, h = self.get_width_height(physical=True)
        key = w, h, self.figure.dpi
        if self._lastKey != key:  # pyright: ignore[reportAttributeAccessIssue]
            self.renderer = _PngRenderer(w, h, self.figure.dpi)
            self._lastKey = key
        return self.renderer

    def print_png(
        self, filename_or_obj: Any, *, metadata: Any = None, pil_kwargs: Any = None, **_: Any
    ) -> None:
        """Draw the figure and write it as a PNG (``savefig``'s other options, such as
        ``facecolor``, are applied by ``savefig`` itself before the draw)."""
        from PIL import Image, PngImagePlugin

        FigureCanvasAgg.draw(self)
        w, h = (int(v) for v in self.get_renderer().get_canvas_width_height())
        img = Image.frombuffer("RGBA", (w, h), np.asarray(self.buffer_rgba()), "raw", "RGBA", 0, 1)
        if cast(tuple[int, int], img.getchannel("A").getextrema())[0] == 255:  # opaque
            img = img.convert("RGB")
        info = PngImagePlugin.PngInfo()
        software = f"Matplotlib version{mpl.__version__}, https://matplotlib.org/"
        for k, v in {"Software": software, **(metadata or {})}.items():
            if v is not None:
                info.add_text(k, str(v))
        dpi = self.figure.dpi
        # the caller's pil_kwargs win, as in matplotlib's own writer (its pnginfo replaces
        # the metadata, its dpi the figure's)
        opts = {"dpi": (dpi, dpi), "pnginfo": info, "compress_level": PNG_COMPRESS_LEVEL}
        img.save(filename_or_obj, format="png", **{**opts, **(pil_kwargs or {})})
