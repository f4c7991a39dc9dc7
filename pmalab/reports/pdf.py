"""Writing a multi-page report: the one place that turns page figures into a PDF.

The PDF is written under a hidden temporary name and renamed only when every page is
in, so a failed or interrupted report leaves no half file; each page may also be exported
as PNG/SVG (refused up front when such a file exists without ``force``).
"""

from __future__ import annotations

import os
import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path

import matplotlib as mpl
from matplotlib.backends.backend_pdf import PdfPages
from matplotlib.figure import Figure
from tqdm import tqdm

from pmalab import __version__
from pmalab.paths import check_output
from pmalab.reports import style
from pmalab.reports.errors import ReportError, report_output


@dataclass
class PageSpec:
    """One page: its file slug, a label for progress lines, and how to draw it."""

    slug: str
    label: str
    make: Callable[[int, int], Figure]  # (page number, page count) -> figure


#: the footer a report adds to each page: (figure, page number, page count) -> None
Footer = Callable[[Figure, int, int], None]


@dataclass
class ReportPlan:
    """A report's pages and footer, as one planning function builds them from its inputs.

    The planning function is module-level and takes picklable arguments (paths as text),
    so a worker process (:func:`parallel_renderer`) rebuilds the very same plan.
    """

    pages: list[PageSpec]
    title: str
    footer: Footer | None = None


def _plan_renderer(
    plan: Callable[..., ReportPlan], args: tuple, png_dir: str | None, svg_dir: str | None
) -> Callable[[int, int, Path], None]:
    """In a worker process: build the plan once and return a function that writes page
    ``i`` of ``n`` to a one-page PDF, footer and PNG/SVG exports (already checked against
    overwriting by the parent) as :func:`write_pdf` draws them in one process."""
    built = plan(*args)
    exports = [(Path(d), ext) for d, ext in ((png_dir, "png"), (svg_dir, "svg")) if d]

    def render(i: int, n: int, path: Path) -> None:
        page = built.pages[i - 1]
        fig = page.make(i, n)
        with mpl.rc_context(style.RC):
            if built.footer is not None:
                built.footer(fig, i, n)
            style.lay_out(fig)
            with PdfPages(path) as pdf:
                style.save_pdf_page(pdf, fig)
        _export(fig, exports, f"{i:02d}-{page.slug}")

    return render


def _export(fig: Figure, exports: Sequence[tuple[Path, str]], stem: str) -> None:
    """Export a page just drawn into the PDF as ``<dir>/<stem>.<ext>`` for each of
    ``exports`` (checked against overwriting by the caller), 150 dpi, in the layout the PDF
    page has (:func:`style.keep_layout`): the same page, not a second layout."""
    if not exports:
        return
    style.keep_layout(fig)
    for d, ext in exports:
        style.save_figure(fig, d / f"{stem}.{ext}", force=True, dpi=150)


def parallel_renderer(
    plan: Callable[..., ReportPlan],
    args: tuple,
    n: int,
    *,
    jobs: int | None,
    start_method: str | None = None,
    png_dir: str | Path | None = None,
    svg_dir: str | Path | None = None,
) -> Callable[[Path, Callable[[int], None]], list[Path]] | None:
    """The ``parallel`` argument of :func:`write_pdf` for a report of ``n`` pages planned by
    ``plan(*args)``: ``jobs`` worker processes (None: the CPUs this process may use), or
    None (render here) for one job or one page."""
    from pmalab.reports.parallel import default_jobs, render_parallel

    jobs = default_jobs() if jobs is None else jobs
    if jobs <= 1 or n <= 1:
        return None
    setup_args = (
        plan,
        args,
        None if png_dir is None else str(png_dir),
        None if svg_dir is None else str(svg_dir),
    )

    def render_all(tmpdir: Path, done: Callable[[int], None]) -> list[Path]:
        return render_parallel(
            _plan_renderer, setup_args, n, tmpdir, jobs=jobs, start_method=start_method, done=done
        )

    return render_all


def write_plan(
    plan: Callable[..., ReportPlan],
    args: tuple,
    out: str | Path,
    force: bool = False,
    *,
    subject: str = "",
    png_dir: str | Path | None = None,
    svg_dir: str | Path | None = None,
    progress: Callable[[str], None] | None = None,
    bar: bool = False,
    jobs: int | None = None,
    start_method: str | None = None,
) -> Path:
    """Plan a report with ``plan(*args)`` and render it into the PDF ``out``.

    The one path every report takes: ``out`` is checked (refused when it exists without
    ``force``), the plan built here, and its pages drawn by ``jobs`` worker processes
    (default: the CPUs this process may use; 1 draws them in this process), each worker
    rebuilding the same plan from ``args`` (picklable: paths as text). The PDF's pages are
    the same either way.

    Parameters
    ----------
    plan
        The report's module-level planning function.
    args
        Its arguments.
    out
        The PDF to write (a hidden temporary file until every page is in).
    force
        Overwrite ``out`` and page exports.
    subject
        The PDF's Subject metadata.
    png_dir, svg_dir
        Export every page as PNG/SVG there too.
    progress
        Called with one line per page.
    bar
        Show a progress bar.
    jobs
        Worker processes drawing the pages.
    start_method
        The workers' multiprocessing start method (default: the platform's).

    Returns
    -------
    Path
        ``out``.
    """
    out = report_output(Path(out), force)
    built = plan(*args)
    return write_pdf(
        out,
        built.pages,
        title=built.title,
        subject=subject,
        force=force,
        png_dir=png_dir,
        svg_dir=svg_dir,
        progress=progress,
        bar=bar,
        footer=built.footer,
        parallel=parallel_renderer(
            plan,
            args,
            len(built.pages),
            jobs=jobs,
            start_method=start_method,
            png_dir=png_dir,
            svg_dir=svg_dir,
        ),
    )


def _page_bar(n: int, bar: bool) -> tqdm:
    """The progress bar of a report's ``n`` pages on stderr (off unless ``bar``)."""
    return tqdm(
        total=n,
        desc="report",
        unit="page",
        file=sys.stderr,
        disable=not bar,
        leave=False,
        dynamic_ncols=True,
    )


def write_pdf(
    out: Path,
    pages: Sequence[PageSpec],
    *,
    title: str,
    subject: str = "",
    force: bool = False,
    png_dir: str | Path | None = None,
    svg_dir: str | Path | None = None,
    progress: Callable[[str], None] | None = None,
    bar: bool = False,
    footer: Footer | None = None,
    parallel: Callable[[Path, Callable[[int], None]], list[Path]] | None = None,
) -> Path:
    """Render ``pages`` into ``out`` (see the module docstring); returns ``out``.

    With ``parallel``, the pages are not drawn here: ``parallel(tmpdir, done)`` renders
    them (and their PNG/SVG exports) into one-page PDFs in ``tmpdir``, calling
    ``done(i)`` as page ``i`` is ready, and returns those files in page order; they are
    joined into ``out`` (:func:`pmalab.reports.parallel.join_pdfs`).
    """
    exports: list[tuple[Path, str]] = []
    for d, ext in ((png_dir, "png"), (svg_dir, "svg")):
        if d is None:
            continue
        d = Path(d)
        if d.exists() and not d.is_dir():
            raise ReportError(f"{d}: not a directory")
        for i, p in enumerate(pages, 1):
            check_output(d / f"{i:02d}-{p.slug}.{ext}", force)
        exports.append((d, ext))
    tmp = out.with_name(f".{out.name}.part")
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
        tmp.touch()
    except OSError as exc:
        raise ReportError(f"{out}: cannot write ({exc.strerror or exc})") from None
    n = len(pages)
    meta = {"Title": title, "Creator": f"pmalab {__version__}", "CreationDate": datetime.now(UTC)}
    if subject:
        meta["Subject"] = subject
    try:
        if parallel is not None:
            _write_parallel(tmp, pages, meta, parallel, progress, bar)
            os.replace(tmp, out)
            return out
        with (
            PdfPages(tmp, metadata=meta) as pdf,
            _page_bar(n, bar) as pbar,
        ):
            for i, page in enumerate(pages, 1):
                pbar.set_postfix_str(page.label[:48], refresh=True)
                fig = page.make(i, n)
                with mpl.rc_context(style.RC):
                    if footer is not None:
                        footer(fig, i, n)
                    style.lay_out(fig)
                    style.save_pdf_page(pdf, fig)
                _export(fig, exports, f"{i:02d}-{page.slug}")
                if progress is not None:
                    progress(f"page {i}/{n}: {page.label}")
                pbar.update(1)
                del fig
        os.replace(tmp, out)
    finally:
        if tmp.exists():
            tmp.unlink()
    return out


def _write_parallel(
    tmp: Path,
    pages: Sequence[PageSpec],
    meta: dict,
    parallel: Callable[[Path, Callable[[int], None]], list[Path]],
    progress: Callable[[str], None] | None,
    bar: bool,
) -> None:
    """Render through ``parallel`` into a scratch directory and join the pages."""
    import tempfile

    from pmalab.reports.parallel import join_pdfs

    n = len(pages)
    with (
        tempfile.TemporaryDirectory(prefix=".pmalab-report-", dir=tmp.parent) as scratch,
        _page_bar(n, bar) as pbar,
    ):

        def done(i: int) -> None:
            if progress is not None:
                progress(f"page {i}/{n}: {pages[i - 1].label}")
            pbar.update(1)

        parts = parallel(Path(scratch), done)
        join_pdfs(parts, tmp, meta)
