"""Pressure labels against measurements for identification: warn, report, or replace.

:func:`check_runs` compares every run's nominal pressure with its measured mean
(:mod:`pmalab.pressure_labels`); :func:`use_measured` gives each run its measured mean as
its pressure (``--pressure measured``), keeping the label as ``muscle_pressure_label_MPa``.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace

import numpy as np

from pmalab.pressure_labels import LabelCheck, check_labels
from pmalab.runfile import Run

#: how a run's pressure is taken: its label (protocol, file name) or its measured mean
PRESSURE_SOURCES = ("nominal", "measured")


def check_runs(runs: Sequence[Run], whole_run: bool = False) -> list[LabelCheck]:
    """Label vs measured mean of each run (its full-amplitude cycles unless ``whole_run``)."""
    parts = [r if whole_run else r.steady() for r in runs]
    return check_labels(
        (r.label, float(r.nominal_pressure), np.asarray(p.muscle_pressure, float))
        for r, p in zip(runs, parts)
    )


def use_measured(runs: Sequence[Run], whole_run: bool = False) -> list[Run]:
    """Each run with its measured mean pressure (MPa) as its nominal pressure; the label is
    kept in the attr ``muscle_pressure_label_MPa``."""
    out = []
    for r, c in zip(runs, check_runs(runs, whole_run)):
        attrs = dict(r.attrs)
        attrs.setdefault("muscle_pressure_label_MPa", attrs.get("muscle_pressure_MPa"))
        attrs["muscle_pressure_MPa"] = float(c.measured_MPa)
        out.append(replace(r, attrs=attrs))
    return out
