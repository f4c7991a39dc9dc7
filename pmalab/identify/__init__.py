"""Identification: hysteresis models, fitting, pressure quadratics, validation, diagnosis.

Notebook use (names are imported lazily so ``pmalab --help`` stays fast)::

    from pmalab.identify import load, identify
    runs = load("campaign.h5")
    res = identify(runs, model="bouc-wen", validate=load("held-out.h5"))
    res.predict(runs[0]); res.plot_loops(); res.save("out/")
    d = diagnose(runs, model="bouc-wen")   # d.ranking, d.ladder: DataFrames; d.summary

Lower level: ``fit_run``, ``fit_campaign``, ``predict_run``, ``metrics``, ``ForceModel``,
``get_law`` (a law with its per-sample ``step``), ``diagnose``.

Layout (one-way imports, checked by import-linter): ``laws/`` and ``effects/`` (what the
model is) → ``estimation/`` (the one fitter) → ``campaign/`` (identification, pressure
laws, validation) → ``diagnosis/`` (ranking and ladder through the same identification) →
``api``/``outputs``/``cli``.
"""

from __future__ import annotations

from pmalab.lazy import lazy_exports

__getattr__, __all__ = lazy_exports(
    __name__,
    {
        "load": "pmalab.identify.api",
        "identify": "pmalab.identify.api",
        "Identification": "pmalab.identify.api",
        "fit_run": "pmalab.identify.estimation.single",
        "FitResult": "pmalab.identify.estimation.single",
        "diagnose": "pmalab.identify.api",
        "DiagnosisResult": "pmalab.identify.api",
        "fit_campaign": "pmalab.identify.campaign",
        "predict_run": "pmalab.identify.campaign",
        "CampaignFit": "pmalab.identify.campaign",
        "metrics": "pmalab.identify.metrics",
        "ForceModel": "pmalab.identify.model",
        "Signals": "pmalab.identify.signals",
    },
)
