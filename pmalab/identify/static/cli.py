"""``pmalab identify --static MAP``: the static characterization from the command line.

Chosen with ``--static`` (``linear``, ``chou-hannaford``, ``tondu-lopez``), and taken
automatically when an input run is not isobaric (an isometric record has no stroke for the
isobaric model).  Writes ``OUT/identification.json`` (the contract's keys plus
``static_map``, ``hysteresis`` and per-run ``test_type``) and ``OUT/predictions.h5``.
"""

from __future__ import annotations

import json
import math
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from pmalab.arguments import fixes
from pmalab.errors import PmalabError
from pmalab.runfile import Run


def check_geometry(value: float | None, option: str) -> float | None:
    """A measured length or diameter (mm), refused when no muscle has it."""
    if value is None:
        return None
    if not (math.isfinite(value) and 0 < value <= 5000):
        raise PmalabError(f"{option}: must be a length in mm > 0 and ≤ 5000, got {value:g}")
    return float(value)


def run_static(
    args: Any,
    runs: Sequence[Run],
    val: Sequence[Run],
    out: Path,
    *,
    auto: bool = False,
) -> int:
    """Fit, write and print the static identification (``args``: the identify namespace)."""
    from pmalab.identify.predictions import PredictionItem, write_predictions_file
    from pmalab.identify.static.fit import (
        DRIVES,
        StaticModel,
        default_drive,
        fit_static,
        summary_doc,
    )
    from pmalab.identify.static.maps import Geometry, get_static_map
    from pmalab.paths import check_output, write_together

    for opt, given in (
        ("--add", bool(getattr(args, "add", None))),
        ("--effects", bool(getattr(args, "effects", None))),
        ("--free", bool(getattr(args, "free", None))),
        ("--output position", getattr(args, "output", "force") != "force"),
    ):
        if given:
            raise PmalabError(
                f"{opt}: not part of the static characterization (a static map and a law); "
                "identify isobaric runs for effects and output error"
            )
    geometry = Geometry(
        length_mm=check_geometry(args.length, "--length"),
        diameter_mm=check_geometry(args.diameter, "--diameter"),
    )
    smap = get_static_map(args.static or "linear", geometry)
    drive = args.drive or default_drive(runs)
    if drive not in DRIVES:
        raise PmalabError(f"--drive {drive}: one of {', '.join(DRIVES)}")
    law = None if args.model == "none" else args.model
    model = StaticModel(smap, law, drive, args.loop_scale)
    if auto:
        kinds = ", ".join(sorted({r.test_type for r in runs}))
        print(
            f"{kinds} runs: static characterization with the '{smap.name}' map and "
            f"{'no law' if law is None else law + ' on the ' + drive} (choose --static "
            "chou-hannaford|tondu-lopez|linear and --drive pressure|position|both)",
            file=sys.stderr,
        )
    fixed = fixes(args.fix)
    fit = fit_static(model, runs, val, fixed=fixed)
    doc = summary_doc(fit, {"length_mm": geometry.length_mm, "diameter_mm": geometry.diameter_mm})
    jpath = check_output(out / "identification.json", args.force)
    hpath = check_output(out / "predictions.h5", args.force)
    items = [PredictionItem(rf.rec.run, rf.role, rf.prediction, model.name) for rf in fit.runs]
    items += [
        PredictionItem(rf.rec.run, rf.role, rf.prediction, model.name) for rf in fit.validation
    ]
    out.mkdir(parents=True, exist_ok=True)
    write_together(
        {
            jpath: lambda p: p.write_text(json.dumps(doc, indent=1, allow_nan=False) + "\n"),
            hpath: lambda p: write_predictions_file(p, items, model.name),
        }
    )
    _print(doc, fit)
    print(f"wrote {jpath} and {hpath}")
    return 0


def _fmt(v: float | None, se: float | None) -> str:
    if v is None:
        return "-"
    return f"{v:.5g}" + (f" ± {se:.2g}" if se is not None else "")


def _print(doc: dict[str, Any], fit: Any) -> None:
    sm = doc["static_map"]
    print(
        f"static map {sm['id']} ({sm['title']}), law "
        f"{doc['hysteresis']['law'] + ' on the ' + doc['hysteresis']['drive'] if doc['hysteresis'] else 'none'}: "
        f"{len(doc['runs'])} identification run(s) ({', '.join(doc['test_types'])}), "
        f"{len(doc['validation'])} validation run(s)"
    )
    for n, p in sm["parameters"].items():
        print(f"  {n:<16} {_fmt(p['value'], p['stderr']):>22} {p['unit']:<10} {p['doc']}")
    for n, p in sm["derived"].items():
        print(f"  {n:<24} {p['value']:>14.5g} {p['unit']:<10} {p['doc']}")
    h = doc["hysteresis"]
    if h:
        for n, p in h["parameters"].items():
            print(f"  {n:<16} {_fmt(p['value'], p['stderr']):>22} {p['unit']:<10} {p['doc']}")
        for k, v in h["loop_half_width_N"].items():
            at = (
                f" at {h['loop_reference_MPa']:.3g} MPa (∝ p)"
                if k == "pressure" and h.get("loop_scale") == "pressure"
                else ""
            )
            print(f"  loop half-width on the {k}: {v:.3g} N{at}")
    w = max(
        [len(f"{Path(r['file'] or '').name}:{r['run']}") for r in doc["runs"] + doc["validation"]]
        + [10]
    )
    for r in [*doc["runs"], *doc["validation"]]:
        label = f"{Path(r['file'] or '').name}:{r['run']}"
        held = (
            f"x={r['held_position_mm']:.3g} mm"
            if "held_position_mm" in r
            else f"p={r['muscle_pressure_MPa']:.4f} MPa"
        )
        verb = "identify" if r["role"] == "identification" else "validate"
        print(
            f"  {verb}  {label:<{w}}  {r['test_type']:<9} {held:<14} fit "
            f"{r['fit_percent']:6.2f} %  rmse {r['rmse']:7.3g} N  "
            f"({r['nrmse'] / max(r['noise_floor_nrmse'], 1e-12):.2f}× the noise floor)"
        )
    for m in fit.messages:
        print(f"warning: {m}", file=sys.stderr)


def run_static_diagnose(
    args: Any, runs: Sequence[Run], val: Sequence[Run], out: Path, laws: list[str] | None
) -> int:
    """``pmalab diagnose`` on static test types: the laws ranked against the map alone on
    held-out runs (:mod:`pmalab.identify.static.diagnose`); writes ``OUT/diagnosis.json``."""
    from pmalab.identify.schema import check_diagnosis
    from pmalab.identify.static.diagnose import diagnose_static
    from pmalab.identify.static.maps import Geometry, get_static_map
    from pmalab.paths import check_output, write_together

    geometry = Geometry(
        length_mm=check_geometry(args.length, "--length"),
        diameter_mm=check_geometry(args.diameter, "--diameter"),
    )
    smap = get_static_map(args.static or "linear", geometry)
    try:
        doc = diagnose_static(
            smap, runs, val, laws=laws, drive=args.drive, loop_scale=args.loop_scale
        )
    except ValueError as exc:
        raise PmalabError(f"diagnose: {exc}") from None
    check_diagnosis(doc, "diagnosis.json")
    jpath = check_output(out / "diagnosis.json", args.force)
    out.mkdir(parents=True, exist_ok=True)
    write_together(
        {jpath: lambda p: p.write_text(json.dumps(doc, indent=1, allow_nan=False) + "\n")}
    )
    floor = doc["noise_floor"]["mean_nrmse"]
    print(f"Held out ({doc['settings']['validation']}): {', '.join(doc['settings']['held_out'])}")
    print(
        f"Laws on the {doc['drive']} against the static map {smap.name} alone "
        f"(held-out nrmse; noise floor {floor:.4f}):"
    )
    print(f"  {'static map alone':<22} {doc['ladder'][0]['nrmse']:.4f}")
    for r in doc["laws"]:
        if r.get("status") == "failed":
            print(f"  {r['law']:<22} failed: {r['reason']}")
            continue
        print(
            f"  {r['law']:<22} {r['nrmse_after']:.4f}  ({r['nrmse_after'] / floor:.2f}× floor, "
            f"−{r['fall_percent']:.0f} %){'  significant' if r['significant'] else ''}"
        )
    print(doc["summary"])
    print(f"wrote {jpath}")
    return 0
