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

from pmalab.lazy import lazy_exports
from pmalab.reports.errors import ReportError

__getattr__, _names = lazy_exports(
    __name__,
    {
        "build_report": "pmalab.reports.build",
        "plan_pages": "pmalab.reports.build",
        "save_figure": "pmalab.reports.style",
        "load_report_dir": "pmalab.reports.data",
    },
)
__all__ = ["ReportError", *_names]
