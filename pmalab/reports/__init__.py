"""Reports: plots and the multi-page PDF report of an identification/diagnosis directory.

Public API (imported lazily so ``pmalab`` starts without matplotlib):

* :func:`build_report` ``(directory, out, force=False, *, png_dir=None, svg_dir=None,
  progress=None) -> Path`` — the PDF;
* :func:`save_figure` ``(fig, path, *, force=False)`` — PNG/SVG export of one figure;
* :class:`ReportError` — bad result directory (one line naming file and key);
* :mod:`pmalab.reports.figures` — every figure, usable alone.

Never imports ``pmalab.rig`` or ``pmalab.acquisition`` (import-linter contract).
"""

from __future__ import annotations

from typing import Any

from pmalab.reports.errors import ReportError

__all__ = ["ReportError", "build_report", "load_report_dir", "plan_pages", "save_figure"]


def __getattr__(name: str) -> Any:
    if name in ("build_report", "plan_pages"):
        from pmalab.reports import build

        return getattr(build, name)
    if name == "save_figure":
        from pmalab.reports.style import save_figure

        return save_figure
    if name == "load_report_dir":
        from pmalab.reports.data import load_report_dir

        return load_report_dir
    raise AttributeError(f"module 'pmalab.reports' has no attribute {name!r}")
