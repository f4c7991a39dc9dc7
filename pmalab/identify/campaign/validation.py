"""Validation: the pressure-law model's free-run prediction of held-out runs.

One function, :func:`validate_runs`, predicts held-out runs for ``pmalab identify`` and for
every candidate ``pmalab diagnose`` scores, so the validation error a user reads is the same
number wherever it appears.  Each run's record parameters (start state, record nuisances)
are set by the record policy of :mod:`pmalab.identify.estimation.records`: under
``initial="estimate"`` they are fitted on the run's early part and the metrics are those of
the rest (``Validation.scored_from``), so a record parameter must predict, not absorb.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np

from pmalab.identify.campaign.fit import CampaignFit
from pmalab.identify.estimation.records import scored_from
from pmalab.identify.metrics import metrics
from pmalab.identify.signals import Signals
from pmalab.runfile import Run

#: a prediction counts as diverged when it leaves the measured force band by more than this
#: many times the measured range (or is not finite)
DIVERGED_RANGE_FACTOR = 2.0
#: validation statuses: "ok", "extrapolated" (pressure outside the identified range),
#: "diverged" (metrics withheld: see :func:`check_prediction`)
VALIDATION_STATUSES = ("ok", "extrapolated", "diverged")


def check_prediction(
    measured: np.ndarray, predicted: np.ndarray, what: str = "force", unit: str = "N"
) -> str | None:
    """Why a prediction is unusable (non-finite, or far outside the measured force band), or None.

    Band: [min F − 2·range, max F + 2·range] of the measured force (N).  A model whose
    hysteretic state runs away produces forces of thousands of N on a 700 N record; its
    "fit %" would be a meaningless large negative number, so it is reported as diverged.
    """
    y = np.asarray(measured, dtype=np.float64)
    yh = np.asarray(predicted, dtype=np.float64)
    if not np.all(np.isfinite(yh)):
        return f"prediction is not finite on {int(np.sum(~np.isfinite(yh)))} sample(s)"
    lo, hi = float(np.min(y)), float(np.max(y))
    rng = max(hi - lo, 1e-9)
    worst = float(np.max(np.maximum(yh - hi, lo - yh)))
    if worst > DIVERGED_RANGE_FACTOR * rng:
        return (
            f"prediction leaves the measured {what} band [{lo:.4g}, {hi:.4g}] {unit} by up "
            f"to {worst:.4g} {unit} (> {DIVERGED_RANGE_FACTOR:g}× its range)"
        )
    return None


@dataclass
class Validation:
    """One held-out run predicted by the pressure-law model.

    ``status``: ``"ok"``, ``"extrapolated"`` (the run's pressure lies outside the identified
    range: θ(p) is extrapolated and clipped into the law's bounds) or ``"diverged"`` (the
    prediction ran away; ``message`` says why).  A diverged run's ``metrics`` are still
    computed (NaN where the prediction is not finite) so tools reading
    ``identification.json`` keep working, but the CLI, ``repr`` and tables say DIVERGED
    instead of printing its meaningless fit %.
    """

    run: Run
    force_model: np.ndarray
    metrics: dict
    x_drive: np.ndarray
    status: str = "ok"
    message: str = ""
    #: the simulated position (mm) when the model was fitted on position (``--output
    #: position``); its errors are in ``metrics`` (``rmse_position_m`` ...)
    position_model: np.ndarray | None = None
    #: first sample the metrics are computed from (after the early part on which the
    #: record parameters were estimated; 0 when nothing of the record was fitted)
    scored_from: int = 0

    @property
    def scored(self) -> slice:
        """The samples the metrics score."""
        return slice(self.scored_from, None)

    @property
    def fit_percent(self) -> float:
        return float(self.metrics["fit_percent"])

    @property
    def diverged(self) -> bool:
        return self.status == "diverged"


def validate_runs(
    cf: CampaignFit, runs: Iterable[Run], initial: str = "estimate"
) -> tuple[list[Validation], list[str]]:
    """Predict each held-out run with ``cf``'s pressure laws; returns (validations, warnings)."""
    out: list[Validation] = []
    warnings: list[str] = []
    for r in runs:
        sig = Signals.from_run(r)
        with np.errstate(all="ignore"):
            fm = cf.predict(sig, force=r.force, initial=initial)
        status, msg = "ok", ""
        p = float(r.nominal_pressure)
        if cf.extrapolates(p):
            lo, hi = cf.pressure_range
            status = "extrapolated"
            msg = (
                f"{p:g} MPa is outside the identified range [{lo:g}, {hi:g}] MPa: "
                "θ(p) extrapolated and clipped into the law's bounds"
            )
            warnings.append(f"{r.label}: {msg}")
        i0 = scored_from(sig, initial)
        with np.errstate(all="ignore"):
            m = metrics(r.force[i0:], fm[i0:], sig.x[i0:])
        why = check_prediction(r.force, fm)
        if why is not None:
            status, msg = "diverged", why + (f"; {msg}" if msg else "")
            warnings.append(
                f"{r.label}: the {cf.pressure_model} pressure-law model diverged on this "
                f"validation run ({why}); its fit % is meaningless"
            )
        xm = None
        if cf.output == "position":
            xm, m = _position(cf, r, sig, m)
            why = check_prediction(r.position, xm, "position", "mm")
            if why is not None and status != "diverged":
                status, msg = "diverged", why
                warnings.append(f"{r.label}: the simulated position diverged ({why})")
        out.append(
            Validation(
                run=r,
                force_model=fm,
                metrics=m,
                x_drive=sig.x,
                status=status,
                message=msg,
                position_model=xm,
                scored_from=i0,
            )
        )
    return out, warnings


def _position(cf: CampaignFit, r: Run, sig: Signals, m: dict) -> tuple[np.ndarray, dict]:
    """The simulated position of a held-out run (start state estimated on its first
    0.2 s) and the force metrics ``m`` with the position errors added."""
    from pmalab.identify.estimation.output_error import (
        position_data,
        position_metrics,
        predict_position,
    )

    d = position_data(r.label, sig, r.force, r.position)
    th = cf.theta(float(r.nominal_pressure))
    with np.errstate(all="ignore"):
        xm, _ = predict_position(cf.model, th, d, cf.bounds)
    return xm, {**m, **position_metrics(r.position, xm)}


def fit_and_validate(
    train: list[Run],
    model,
    held_out: Iterable[Run],
    *,
    initial: str = "estimate",
    output: str = "force",
    **fit_kwargs,
) -> tuple[CampaignFit, list[Validation], list[str]]:
    """THE identification: :func:`~pmalab.identify.campaign.fit.fit_campaign` on ``train``,
    then :func:`validate_runs` on ``held_out``.  ``pmalab identify`` and every candidate
    that ``pmalab diagnose`` scores go through this one function.

    A model whose effects take the runs' pressure from the measurement
    (``ForceModel.measured_pressure``: ``pressure-offset``) gets every run, identification
    and held-out, at its measured mean pressure (the runs as given: their samples'
    mean) — what ``--pressure measured`` does."""
    from pmalab.identify.campaign.fit import _as_model, fit_campaign

    if not isinstance(model, str) and _as_model(model).measured_pressure:
        from pmalab.identify.labels import use_measured

        train = use_measured(train, whole_run=True)
        held_out = use_measured(list(held_out), whole_run=True)

    cf = fit_campaign(train, model, **fit_kwargs)
    if output == "position":
        from pmalab.identify.campaign.fit import refine_output_error

        cf = refine_output_error(cf, train)
    vals, warns = validate_runs(cf, held_out, initial)
    return cf, vals, warns
