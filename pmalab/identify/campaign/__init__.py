"""A campaign: per-run fits, pressure laws and validation (one identification).

:func:`~.fit.fit_campaign` fits every identification run and the pressure laws;
:func:`~.validation.fit_and_validate` adds the held-out runs' validation — the single
identification that ``pmalab identify`` and ``pmalab diagnose`` both run.
"""

from __future__ import annotations

from pmalab.identify.campaign.fit import (
    CampaignFit,
    ModelSpec,
    RunFit,
    fit_campaign,
    predict_run,
    refine_pressure_laws,
)
from pmalab.identify.campaign.validation import (
    Validation,
    check_prediction,
    fit_and_validate,
    validate_runs,
)

__all__ = [
    "CampaignFit",
    "ModelSpec",
    "RunFit",
    "Validation",
    "check_prediction",
    "fit_and_validate",
    "fit_campaign",
    "predict_run",
    "refine_pressure_laws",
    "validate_runs",
]
