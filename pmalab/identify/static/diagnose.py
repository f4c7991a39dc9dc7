"""``pmalab diagnose`` on static test types: which hysteresis law the static map lacks.

The ladder of a static characterization: step 0 is the static map alone; then every law
(``--laws``, default all) driven by the test's drive (pressure for isometric/isotonic runs,
contraction for isobaric ones, both for free runs) is identified on the same runs and
scored on the same held-out runs (``--validate``, else the run whose held level is the
campaign's median: a held-out length), with the same refit of each held-out run's start
state that ``identify --static`` uses — so the fall a law shows here is the fall the user
gets.  A law counts as significant when it lowers the mean held-out nrmse by more than the
held-out runs' own noise floor (a fall the noise alone cannot make); the best significant
law is the ladder's step 1.  ``verdict`` says whether the best model reaches 1.5× the
noise floor (``floor``) or leaves something ``unexplained``.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from pmalab.identify.laws import LAWS
from pmalab.identify.static.fit import StaticFit, StaticModel, default_drive, fit_static
from pmalab.identify.static.maps import StaticMap
from pmalab.runfile import Run

#: a model within this multiple of the noise floor explains the data
FLOOR_MULTIPLE = 1.5


def held_out_level(runs: Sequence[Run]) -> tuple[list[Run], list[Run]]:
    """(identification, held out): the run at the campaign's median held level (the held
    contraction of isometric runs, the pressure of isobaric ones) is held out."""
    if len(runs) < 3:
        raise ValueError("a static diagnosis without --validate needs ≥ 3 runs (one held out)")

    def level(r: Run) -> float:
        if r.test_type == "isometric":
            return float(r.attrs.get("held_position_mm", np.median(r.position)))
        return float(r.nominal_pressure)

    order = sorted(runs, key=level)
    mid = order[len(order) // 2]
    return [r for r in runs if r is not mid], [mid]


def _mean(fit: StaticFit) -> float:
    return float(np.mean([v.nrmse for v in fit.validation]))


def diagnose_static(
    smap: StaticMap,
    runs: Sequence[Run],
    validate: Sequence[Run] = (),
    *,
    laws: Sequence[str] | None = None,
    drive: str | None = None,
    loop_scale: str = "none",
) -> dict[str, Any]:
    """The static diagnosis as ``diagnosis.json`` (the contract's keys; module docstring)."""
    if validate:
        ident, held = list(runs), list(validate)
    else:
        ident, held = held_out_level(runs)
    drv = drive or default_drive(ident)
    base = fit_static(StaticModel(smap, None, drv), ident, held)
    before = _mean(base)
    floors = {v.rec.label: v.noise_floor_nrmse for v in base.validation}
    floor = float(np.mean(list(floors.values())))
    rows: list[dict[str, Any]] = []
    fits: dict[str, StaticFit] = {}
    for name in laws if laws is not None else list(LAWS):
        try:
            fit = fit_static(StaticModel(smap, name, drv, loop_scale), ident, held)
        except Exception as exc:  # a failed fit is reported, never ranked
            rows.append(
                {
                    "law": name,
                    "nrmse_before": before,
                    "nrmse_after": before,
                    "fall_percent": None,
                    "significant": False,
                    "status": "failed",
                    "reason": str(exc).splitlines()[0][:200] if str(exc) else type(exc).__name__,
                }
            )
            continue
        after = _mean(fit)
        fits[name] = fit
        rows.append(
            {
                "law": name,
                "nrmse_before": before,
                "nrmse_after": after,
                "fall_percent": 100.0 * (before - after) / before if before > 0 else 0.0,
                "significant": bool(before - after > floor),
                "gain_x_floor": (before - after) / floor if floor > 0 else None,
                "per_run_after": [v.nrmse for v in fit.validation],
            }
        )
    ok = [r for r in rows if r.get("status") != "failed"]
    failed = [r for r in rows if r.get("status") == "failed"]
    ok.sort(key=lambda r: r["nrmse_after"])
    ladder = [
        {
            "step": 0,
            "nrmse": before,
            "fit_percent": 100.0 * (1.0 - before),
            "effects": [],
            "added": None,
            "law": None,
            "model": base.model.name,
            "per_run": [v.nrmse for v in base.validation],
        }
    ]
    best = next((r for r in ok if r["significant"]), None)
    final = base
    if best is not None:
        final = fits[best["law"]]
        ladder.append(
            {
                "step": 1,
                "nrmse": best["nrmse_after"],
                "fit_percent": 100.0 * (1.0 - best["nrmse_after"]),
                "effects": [],
                "added": None,
                "law": best["law"],
                "switched_law": best["law"],
                "model": final.model.name,
                "per_run": best["per_run_after"],
            }
        )
    end = ladder[-1]["nrmse"]
    verdict = "floor" if end <= FLOOR_MULTIPLE * floor else "unexplained"
    summary = (
        f"static map {smap.name} alone: held-out nrmse {before:.4f} "
        f"({before / floor:.1f}× the noise floor {floor:.4f}); "
        + (
            f"{best['law']} on the {drv}: {best['nrmse_after']:.4f} "
            f"({best['nrmse_after'] / floor:.2f}× the floor, −{best['fall_percent']:.0f} %)"
            if best
            else "no law lowers it by more than the noise floor"
        )
        + ("" if verdict == "floor" else "; the rest is not explained by these laws")
    )
    return {
        "model": f"{smap.name} (static map)",
        "kind": "static",
        "static_map": smap.name,
        "drive": drv,
        "ranking": [],
        "ambiguous": [],
        "ladder": ladder,
        "laws": ok + failed,
        "final_model": final.model.name,
        "final_law": best["law"] if best else "none",
        "noise_floor": {
            "mean_nrmse": floor,
            "per_run": floors,
            "method": "the held-out runs' force noise (identify.noise)",
        },
        "verdict": verdict,
        "summary": summary,
        "settings": {
            "held_out": [v.rec.label for v in base.validation],
            "validation": "--validate" if validate else "the run at the median held level",
            "test_types": sorted({r.test_type for r in ident}),
        },
    }
