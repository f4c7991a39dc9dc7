"""Rendering report pages in parallel processes and joining them into one PDF.

Drawing a page into the PDF (layout, tick labels, text, paths) is what a report spends
its time on, and pages are independent, so each worker process renders whole pages into
one-page PDF files and the parent joins them in page order.  Workers receive everything
they need as arguments (the input directories, the page numbers), never through
inherited globals, so the pool works under the ``fork``, ``forkserver`` and ``spawn``
start methods alike.

:func:`join_pdfs` only reads PDFs written by matplotlib's PDF backend (an uncompressed
cross-reference table, one ``/Pages`` node, no object streams): it renumbers their
objects, hangs every page on one new page tree and writes a fresh document
information dictionary.  Page content streams are copied byte for byte, so each page
of the joined file draws exactly what the one-page file draws.
"""

from __future__ import annotations

import os
import re
from collections.abc import Callable, Sequence
from concurrent.futures import ProcessPoolExecutor
from itertools import pairwise
from multiprocessing import get_context
from pathlib import Path
from typing import Any

from pmalab.reports.errors import ReportError

_REF = re.compile(rb"(\d+) 0 R\b")
_TRAILER = re.compile(rb"trailer\s*<<(.*?)>>\s*startxref", re.S)


def default_jobs() -> int:
    """Worker processes a report uses by default: ``$PMALAB_JOBS`` when set, else the
    CPUs this process may run on."""
    from pmalab.arguments import default_jobs as jobs_from_env

    try:
        cpus = max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # not on Linux
        cpus = max(1, os.cpu_count() or 1)
    return jobs_from_env(cpus)


def _objects(data: bytes, name: str) -> tuple[dict[int, bytes], int, int]:
    """The objects of a matplotlib PDF (number -> bytes between ``obj`` and ``endobj``),
    its catalog and page-tree object numbers."""
    start = data.rfind(b"startxref")
    if start < 0:
        raise ReportError(f"{name}: not a complete PDF")
    xref = int(data[start + 9 :].split()[0])
    head = data[xref:].split(b"\n", 2)
    if head[0].strip() != b"xref":
        raise ReportError(f"{name}: no cross-reference table")
    first, count = (int(v) for v in head[1].split())
    table = head[2]
    offsets: dict[int, int] = {}
    for k in range(count):
        entry = table[20 * k : 20 * k + 20].split()
        if entry[2] == b"n":
            offsets[first + k] = int(entry[0])
    trailer = _TRAILER.search(data, xref)
    root = re.search(rb"/Root (\d+) 0 R", trailer.group(1)) if trailer else None
    if root is None:
        raise ReportError(f"{name}: no catalog")
    bounds = [*sorted(offsets.values()), xref]
    nxt = dict(pairwise(bounds))
    objs: dict[int, bytes] = {}
    for num, off in offsets.items():
        chunk = data[off : nxt[off]]
        begin = chunk.index(b" obj") + 4
        end = chunk.rindex(b"endobj")
        objs[num] = chunk[begin:end].strip(b"\r\n")
    catalog = int(root.group(1))
    pages = re.search(rb"/Pages (\d+) 0 R", objs[catalog])
    if pages is None:
        raise ReportError(f"{name}: no page tree")
    return objs, catalog, int(pages.group(1))


def join_pdfs(parts: Sequence[Path], out: Path, info: dict[str, Any]) -> None:
    """Write the pages of the PDFs ``parts`` (matplotlib-written), in order, into ``out``
    with the document information ``info`` (as for :class:`PdfPages` ``metadata``)."""
    from matplotlib.backends.backend_pdf import _create_pdf_info_dict, pdfRepr

    body: list[tuple[int, bytes]] = []
    kids: list[int] = []
    tree = 1  # the new page tree; the catalog is 2, the info dictionary 3
    base = 3
    for part in parts:
        objs, catalog, pages = _objects(part.read_bytes(), str(part))
        info_ref = None
        trailer = _TRAILER.search(part.read_bytes())
        if trailer is not None:
            m = re.search(rb"/Info (\d+) 0 R", trailer.group(1))
            info_ref = int(m.group(1)) if m else None
        skip = {catalog, pages, info_ref}

        def renumber(m: re.Match[bytes], base: int = base, pages: int = pages) -> bytes:
            n = int(m.group(1))
            return b"%d 0 R" % (tree if n == pages else n + base)

        for num in sorted(objs):
            if num in skip:
                continue
            obj = objs[num]
            cut = obj.find(b"stream")
            head, tail = (obj, b"") if cut < 0 else (obj[:cut], obj[cut:])
            head = _REF.sub(renumber, head)
            if b"/Type /Page " in head or b"/Type /Page\n" in head:
                kids.append(num + base)
            body.append((num + base, head + tail))
        base += max(objs) + 1
    kids_ref = " ".join(f"{k} 0 R" for k in kids)
    body.append((tree, f"<< /Type /Pages /Kids [ {kids_ref} ] /Count {len(kids)} >>".encode()))
    body.append((2, f"<< /Type /Catalog /Pages {tree} 0 R >>".encode()))
    body.append((3, pdfRepr(_create_pdf_info_dict("pdf", dict(info)))))
    size = max(n for n, _ in body) + 1
    offsets = dict.fromkeys(range(size), 0)
    present = {n for n, _ in body}
    with open(out, "wb") as fh:
        fh.write(b"%PDF-1.4\n%\xac\xdc \xab\xba\n")
        for num, obj in sorted(body):
            offsets[num] = fh.tell()
            fh.write(b"%d 0 obj\n" % num + obj + b"\nendobj\n")
        xref = fh.tell()
        fh.write(b"xref\n0 %d\n0000000000 65535 f \n" % size)
        for num in range(1, size):
            flag = b"n" if num in present else b"f"
            fh.write(b"%010d 00000 %s \n" % (offsets[num], flag))
        fh.write(b"trailer\n<< /Size %d /Root 2 0 R /Info 3 0 R >>\n" % size)
        fh.write(b"startxref\n%d\n%%%%EOF\n" % xref)


#: per-worker state: the render function built once per process by the initializer
_RENDER: list[Callable[[int, int, Path], None]] = []


def _init(setup: Callable[..., Callable[[int, int, Path], None]], args: tuple) -> None:
    """Worker initializer: build the page renderer from explicit, picklable arguments."""
    import matplotlib

    matplotlib.use("Agg")
    _RENDER[:] = [setup(*args)]


def _render(i: int, n: int, path: Path) -> int:
    _RENDER[0](i, n, path)
    return i


def render_parallel(
    setup: Callable[..., Callable[[int, int, Path], None]],
    args: tuple,
    n: int,
    tmpdir: Path,
    *,
    jobs: int,
    start_method: str | None = None,
    done: Callable[[int], None] | None = None,
) -> list[Path]:
    """Render pages ``1..n`` in ``jobs`` processes and return their one-page PDFs in order.

    ``setup(*args)`` runs once in each worker (a module-level function, so it pickles)
    and returns ``render(i, n, path)``, which writes page ``i`` of ``n`` to ``path``.
    ``done(i)`` is called in the parent as page ``i`` is ready, in page order.
    """
    ctx = get_context(start_method)
    paths = [tmpdir / f"page-{i:04d}.pdf" for i in range(1, n + 1)]
    with ProcessPoolExecutor(
        max_workers=max(1, min(jobs, n)), mp_context=ctx, initializer=_init, initargs=(setup, args)
    ) as pool:
        futures = [pool.submit(_render, i, n, p) for i, p in enumerate(paths, 1)]
        for f in futures:
            i = f.result()
            if done is not None:
                done(i)
    return paths
