"""The ``predictions.h5`` format — declared once, written by one function.

Root attrs ``format = "pmalab.predictions"``, ``format_version = 1`` and ``model``; one
group ``/runs/<key>`` per (run, role) with 1-D datasets, each with a ``units`` attr:
``time`` (s), ``position`` (mm, measured, contraction positive), ``muscle_pressure``
(MPa), ``force`` (N, measured tension), ``force_model`` (N) and, for identification runs,
``force_model_quadratic`` (N: the pressure-quadratic model) and, for a model fitted on
position (``identify --output position``), ``position_model`` (mm: the free-run simulated
position, contraction positive); attrs ``role``
(``identification``, ``validation``, ``diagnosis`` = the base model on a held-out run,
``diagnosis-final`` = the final ladder model), ``file``, ``run``, ``muscle_pressure_MPa``,
``frequency_Hz``, ``waveform``, ``model``.  ``pmalab identify`` and ``pmalab diagnose`` write
it; ``pmalab report`` reads it (:mod:`pmalab.reports.data`).
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

PREDICTIONS_FORMAT = "pmalab.predictions"
PREDICTIONS_VERSION = 1


@dataclass
class PredictionItem:
    """One run's prediction: the run (its measured channels), the role, the model's force
    (N) and, for identification runs, the pressure-quadratic model's force."""

    run: Any  # pmalab.runfile.Run
    role: str
    force_model: np.ndarray
    model: str
    force_model_quadratic: np.ndarray | None = None
    position_model: np.ndarray | None = None


def _key(run: Any, role: str, used: set[str]) -> str:
    stem = Path(run.file).stem if run.file else "memory"
    base = f"{stem}__{run.name}" + ("__final" if role == "diagnosis-final" else "")
    base = base.replace("/", "_")
    key, i = base, 2
    while key in used:
        key = f"{base}__{i}"
        i += 1
    used.add(key)
    return key


def write_predictions_file(path: str | Path, items: Iterable[PredictionItem], model: str) -> None:
    """Write ``items`` to a new ``predictions.h5`` at ``path`` (module doc for the layout)."""
    import h5py

    with h5py.File(path, "w") as f:
        f.attrs["format"] = PREDICTIONS_FORMAT
        f.attrs["format_version"] = PREDICTIONS_VERSION
        f.attrs["model"] = model
        grp = f.create_group("runs")
        used: set[str] = set()
        for it in items:
            run = it.run
            g = grp.create_group(_key(run, it.role, used))
            chans = [
                ("time", run.time, "s"),
                ("position", run.position, "mm"),
                ("muscle_pressure", run.muscle_pressure, "MPa"),
                ("force", run.force, "N"),
                ("force_model", it.force_model, "N"),
            ]
            if it.force_model_quadratic is not None:
                chans.append(("force_model_quadratic", it.force_model_quadratic, "N"))
            if it.position_model is not None:
                chans.append(("position_model", it.position_model, "mm"))
            for name, data, unit in chans:
                ds = g.create_dataset(name, data=np.asarray(data, dtype=np.float64))
                ds.attrs["units"] = unit
            g.attrs.update(
                {
                    "role": it.role,
                    "file": run.file,
                    "run": run.name,
                    "muscle_pressure_MPa": float(run.nominal_pressure),
                    "frequency_Hz": float(run.frequency) if run.frequency else float("nan"),
                    "waveform": str(run.attrs.get("waveform", "")),
                    "model": it.model,
                }
            )
