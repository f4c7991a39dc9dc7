"""The report of ``pmalab control`` output: ``pmalab report EXP.h5... --out R.pdf``.

Reads the run files through :mod:`pmalab.runfile` only (reports never import
:mod:`pmalab.control`): a control file is a contract run file whose root attr ``kind`` is
``"control"``.  Pages: one metrics table for every file given, then per experiment file a
response page (position or pressure, error, pressures) and a gains page.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path

from matplotlib.figure import Figure

from pmalab.errors import PmalabError
from pmalab.reports.errors import ReportError
from pmalab.reports.figures_control import (
    ControlFileData,
    ControlRunData,
    gains_figure,
    metrics_table_figure,
    response_figure,
    sim_to_real_figure,
    sim_to_real_pairs,
)
from pmalab.reports.pdf import PageSpec, ReportPlan, write_plan
from pmalab.runfile import decode_attr, open_h5, read_run_datasets, read_runs


def is_control_file(path: str | Path) -> bool:
    """True for an HDF5 run file written by ``pmalab control`` (root attr kind = control)."""
    p = Path(path)
    if not p.is_file() or p.suffix.lower() not in (".h5", ".hdf5"):
        return False
    try:
        f = open_h5(p)
    except PmalabError:
        return False
    try:
        return decode_attr(f.attrs.get("kind")) == "control"
    finally:
        f.close()


def load_control_file(path: str | Path) -> ControlFileData:
    """Every run of a control file with its datasets; :class:`ReportError` on a problem."""
    p = Path(path)
    try:
        runs = read_runs(p)
        f = open_h5(p)
        try:
            root = {k: decode_attr(v, parse_json=True) for k, v in f.attrs.items()}
        finally:
            f.close()
        out = []
        for r in runs:
            attrs = {k: decode_attr(v, parse_json=True) for k, v in r.attrs.items()}
            data = {k: v for k, (v, _) in read_run_datasets(p, r.name).items()}
            out.append(ControlRunData(r.name, attrs, str(attrs.get("status", "completed")), data))
    except PmalabError as exc:
        raise ReportError(str(exc)) from None
    title = str(root.get("experiment") or p.stem) + (
        " [model in the loop]" if root.get("plant") else ""
    )
    return ControlFileData(str(p), title, root, out)


def control_plan(paths: list[str]) -> ReportPlan:
    """The control report's pages (metrics, sim-to-real, then response and gains per file)
    and footer for the control files ``paths``."""
    files = [load_control_file(p) for p in paths]
    pages: list[tuple[str, Callable[[], Figure]]] = [
        ("metrics", lambda: metrics_table_figure(files, "Control experiments: metrics"))
    ]
    pairs = sim_to_real_pairs(files)
    if pairs:  # a model-in-the-loop run and a rig run of the same experiment
        pages.append(("sim-to-real", lambda: sim_to_real_figure(pairs)))
    for f in files:
        pages.append((f"{f.title}-response", lambda f=f: response_figure(f)))
        pages.append((f"{f.title}-gains", lambda f=f: gains_figure(f)))
    specs = [PageSpec(slug, slug, lambda i, n, make=make: make()) for slug, make in pages]

    def footer(fig, i: int, n: int) -> None:
        fig.text(
            0.99,
            0.005,
            f"pmalab control report · page {i}/{n}",
            ha="right",
            va="bottom",
            fontsize=8,
            color="0.4",
        )

    return ReportPlan(specs, "pmalab control report", footer)


def build_control_report(
    paths: Sequence[str | Path],
    out: str | Path,
    force: bool = False,
    *,
    png_dir: str | Path | None = None,
    svg_dir: str | Path | None = None,
    progress: Callable[[str], None] | None = None,
    bar: bool = False,
    jobs: int | None = None,
    start_method: str | None = None,
) -> Path:
    """Render the control report of ``paths`` into ``out`` (a temporary file until complete).

    ``jobs`` worker processes render the pages (default: the CPUs this process may use;
    1 renders in this process); the PDF's pages are the same either way.
    """
    return write_plan(
        control_plan,
        ([str(p) for p in paths],),
        out,
        force,
        png_dir=png_dir,
        svg_dir=svg_dir,
        progress=progress,
        bar=bar,
        jobs=jobs,
        start_method=start_method,
    )
