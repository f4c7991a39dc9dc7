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
from pmalab.reports.errors import ReportError


@dataclass
class PageSpec:
    """One page: its file slug, a label for progress lines, and how to draw it."""

    slug: str
    label: str
    make: Callable[[int, int], Figure]  # (page number, page count) -> figure


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
    footer: Callable[[Figure, int, int], None] | None = None,
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
                    pdf.savefig(fig)
                for d, ext in exports:
                    style.save_figure(fig, d / f"{i:02d}-{page.slug}.{ext}", force=True, dpi=150)
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
