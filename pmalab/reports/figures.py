"""Every report figure, each usable alone: functions take plain data (lists, dicts, numpy
arrays, :class:`~pmalab.reports.data.Trace`) and return a matplotlib Figure; export one
with :func:`save_figure` (PNG/SVG/PDF by suffix).

Units throughout: time s, contraction x mm (positive = shorter), tension F N, pressure
MPa; residuals are F − F_model in N (measured − model).
"""

from pmalab.reports.figures_compare import compare_figure, hysteresis_component_figure
from pmalab.reports.figures_diagnosis import (
    campaign_figure,
    effects_figure,
    ladder_figure,
    plot_binned,
    plot_correlation,
    plot_ladder,
    plot_phase,
    plot_ranking,
    plot_regions,
    ranking_figure,
    residual_diagnostics_figure,
)
from pmalab.reports.figures_parameters import (
    coef_text,
    correlation_figure,
    metrics_table_figure,
    parameter_table_figure,
    parameters_vs_pressure_figure,
    plot_parameter_vs_pressure,
)
from pmalab.reports.figures_signals import (
    before_after_figure,
    error_loop,
    loops_figure,
    time_history_figure,
    validation_figure,
)
from pmalab.reports.figures_text import provenance_figure, title_page_figure
from pmalab.reports.style import save_figure

__all__ = [
    "before_after_figure",
    "campaign_figure",
    "coef_text",
    "compare_figure",
    "correlation_figure",
    "effects_figure",
    "error_loop",
    "hysteresis_component_figure",
    "ladder_figure",
    "loops_figure",
    "metrics_table_figure",
    "parameter_table_figure",
    "parameters_vs_pressure_figure",
    "plot_binned",
    "plot_correlation",
    "plot_ladder",
    "plot_parameter_vs_pressure",
    "plot_phase",
    "plot_ranking",
    "plot_regions",
    "provenance_figure",
    "ranking_figure",
    "residual_diagnostics_figure",
    "save_figure",
    "time_history_figure",
    "title_page_figure",
    "validation_figure",
]
