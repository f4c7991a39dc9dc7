"""The headline figures a user reads, each defined once for the CLI, the demo and the PDF.

* :func:`error_fall`: how much the validation error falls from a base identification to an
  improved one (``identify`` without and with ``--add``): the mean nrmse of the validation
  runs both predicted (free run through the pressure laws, ``identification.json``
  ``"validation"``), before and after.  The demo's summary and the report's
  base-vs-improved pages print this one number.
* :func:`worst_runs`: the runs where the base model fails worst in a diagnosis: largest
  r.m.s. residual (N) of the base model (``diagnosis.json`` ``diagnostics[key].rmse``),
  the definition diagnosis's summary sentence uses; ``pmalab diagnose`` lists them and the
  report draws their residual pages in this order.

Both take the plain JSON documents, so a reader of the files gets the same numbers.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

#: what the error-fall figure is measured on (printed next to it everywhere)
MEASURED_ON = "validation runs, predicted through the pressure laws"
#: what "worst" means (printed next to a worst-run list)
WORST_BY = "largest r.m.s. residual of the base model (N)"


def _key(row: Mapping[str, Any]) -> tuple[str, str]:
    return Path(str(row.get("file", ""))).name, str(row.get("run", ""))


def _finite(v: Any) -> float | None:
    return float(v) if isinstance(v, int | float) and math.isfinite(v) else None


@dataclass(frozen=True)
class RunFall:
    """One validation run: nrmse of the base and of the improved model (None: diverged)."""

    run: str
    muscle_pressure_MPa: float
    before: float | None
    after: float | None


@dataclass(frozen=True)
class ErrorFall:
    """The validation error of a base and an improved identification (nrmse, mean over the
    validation runs both predicted without diverging)."""

    base_model: str
    improved_model: str
    runs: tuple[RunFall, ...]

    @property
    def compared(self) -> tuple[RunFall, ...]:
        """Runs with a finite nrmse under both models (the ones the means are taken on)."""
        return tuple(r for r in self.runs if r.before is not None and r.after is not None)

    @property
    def before(self) -> float:
        c = self.compared
        return sum(r.before for r in c) / len(c) if c else math.nan  # type: ignore[misc]

    @property
    def after(self) -> float:
        c = self.compared
        return sum(r.after for r in c) / len(c) if c else math.nan  # type: ignore[misc]

    @property
    def fall_percent(self) -> float:
        """100·(1 − after/before): positive when the error falls."""
        return 100.0 * (1.0 - self.after / self.before) if self.before > 0 else math.nan

    def sentence(self) -> str:
        """The one line the demo and the report print."""
        n = len(self.compared)
        if not n:
            return "no validation run was predicted by both models: no error fall to report"
        verb = "falls" if self.fall_percent >= 0 else "RISES"
        line = (
            f"validation error {verb} {abs(self.fall_percent):.1f} % (mean nrmse "
            f"{self.before:.4f} → {self.after:.4f}, fit {100 * (1 - self.before):.2f} % → "
            f"{100 * (1 - self.after):.2f} %) on {n} {MEASURED_ON}"
        )
        skipped = len(self.runs) - n
        if skipped:
            line += f"; {skipped} run(s) left out (a prediction diverged)"
        return line


def _model_name(doc: Mapping[str, Any]) -> str:
    effects = [str(e) for e in doc.get("effects") or []]
    return " + ".join([str(doc.get("model", "")), *effects])


def error_fall(base: Mapping[str, Any], improved: Mapping[str, Any]) -> ErrorFall | None:
    """The validation error fall from ``base`` to ``improved`` (two ``identification.json``
    documents); None when they share no validation run."""
    after = {_key(v): v for v in improved.get("validation") or []}
    runs = []
    for v in base.get("validation") or []:
        w = after.get(_key(v))
        if w is None:
            continue
        runs.append(
            RunFall(
                run=str(v.get("run", "")),
                muscle_pressure_MPa=float(v.get("muscle_pressure_MPa", math.nan)),
                before=_finite(v.get("nrmse")),
                after=_finite(w.get("nrmse")),
            )
        )
    if not runs:
        return None
    return ErrorFall(
        base_model=_model_name(base), improved_model=_model_name(improved), runs=tuple(runs)
    )


def worst_runs(diagnostics: Mapping[str, Mapping[str, Any]], n: int | None = None) -> list[str]:
    """Run keys of ``diagnosis.json`` ``diagnostics``, worst first (see :data:`WORST_BY`);
    runs without an ``rmse`` come last, in their original order."""
    keys = list(diagnostics)
    rank = sorted(
        keys, key=lambda k: (-(_finite(diagnostics[k].get("rmse")) or -1.0), keys.index(k))
    )
    return rank if n is None else rank[:n]
