"""The seeds' control experiments as one file, and running them all.

An experiments file (TOML; ``data/control/seed-experiments.toml`` is the seeds' set)::

    [experiments]
    name = "seed-experiments"
    controllers = ["pid", "sn-pid", "rbf-pid"]   # every experiment runs each of them
    duration_s = 20.0                            # default per experiment
    seed = 0                                     # sensor-noise seed of the simulation
    model = ""                                   # identification.json ("" = shipped one)
    truth = ""                                   # simulated muscle truth ("" = default)

    [settings]                                   # optional: ONE set of overrides, applied
    outer = {kp = 12.0}                          # to every controller and experiment

    [[experiment]]
    name = "position-square-15mm"
    reference = "square:0.1Hz:15mm"
    duration_s = 20.0                            # optional
    [experiment.seeds]                           # the papers' figures, for the tables
    S1 = {classic_overshoot_pct = 31.0, adaptive_overshoot_pct = 1.9}

Each experiment writes ``DIR/<name>.h5`` with one run per controller; ``DIR/metrics.json``
holds every run's metrics next to the seeds' figures.  Paths inside the file are relative
to it.  Mistakes are one line naming the file and the field.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from pmalab.config import load_toml
from pmalab.control.controllers import (
    CONTROLLERS,
    CascadeSettings,
    default_settings,
    settings_from_table,
)
from pmalab.control.model import IdentifiedModel
from pmalab.control.record import ControlRecording, planned_attrs, run_metrics
from pmalab.control.reference import Reference, parse_reference
from pmalab.control.runner import run_control
from pmalab.errors import ConfigError, OutputError
from pmalab.paths import DATA_DIR, shipped

SEED_EXPERIMENTS = DATA_DIR / "control" / "seed-experiments.toml"
MAX_DURATION_S = 600.0


@dataclass(frozen=True)
class Experiment:
    name: str
    reference: Reference
    duration_s: float
    seeds: dict[str, Any] = field(default_factory=dict)


@dataclass(frozen=True)
class ExperimentSet:
    name: str
    controllers: list[str]
    experiments: list[Experiment]
    settings: CascadeSettings
    seed: int
    model: Path | None
    truth: Path | None
    path: str
    text: str = ""


def check_duration(v: Any, where: str) -> float:
    """A run length in s: a number in (0, 600]; one-line error otherwise."""
    if (
        isinstance(v, bool)
        or not isinstance(v, int | float)
        or not math.isfinite(v)
        or not 0 < v <= MAX_DURATION_S
    ):
        raise ConfigError(f"{where}: must be a number of seconds in (0, {MAX_DURATION_S:g}]")
    return float(v)


def load_experiments(path: str | Path | None = None) -> ExperimentSet:
    """Read and check an experiments file (``None``: the seeds' set)."""
    # a shipped set by name (seed-experiments) or clone path works from any directory
    p = shipped(path, DATA_DIR / "control") if path is not None else SEED_EXPERIMENTS
    doc, text = load_toml(p, "experiments file", where=str(p))
    where = str(p)
    known = {"experiments", "settings", "experiment"}
    for k in doc:
        if k not in known:
            raise ConfigError(f"{where}: {k}: unknown section (known: {', '.join(sorted(known))})")
    head = doc.get("experiments", {})
    if not isinstance(head, dict):
        raise ConfigError(f"{where}: experiments: must be a table")
    allowed = {"name", "description", "controllers", "duration_s", "seed", "model", "truth"}
    for k in head:
        if k not in allowed:
            raise ConfigError(
                f"{where}: experiments.{k}: unknown key (known: {', '.join(sorted(allowed))})"
            )
    ctrls = head.get("controllers", list(CONTROLLERS))
    if not isinstance(ctrls, list) or not ctrls:
        raise ConfigError(f"{where}: experiments.controllers: must be a non-empty list")
    for c in ctrls:
        if c not in CONTROLLERS:
            raise ConfigError(
                f"{where}: experiments.controllers: unknown '{c}' "
                f"(choose from {', '.join(CONTROLLERS)})"
            )
    dur = check_duration(head.get("duration_s", 20.0), f"{where}: experiments.duration_s")
    seed = head.get("seed", 0)
    if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
        raise ConfigError(f"{where}: experiments.seed: must be an integer ≥ 0")
    base = p.parent

    def rel(key: str) -> Path | None:
        v = head.get(key, "")
        if not isinstance(v, str):
            raise ConfigError(f"{where}: experiments.{key}: must be a path (text)")
        if not v:
            return None
        q = (base / v) if not Path(v).is_absolute() else Path(v)
        if not q.exists():
            raise ConfigError(f"{where}: experiments.{key}: {q}: no such file")
        return q

    settings = default_settings()
    if "settings" in doc:
        if not isinstance(doc["settings"], dict):
            raise ConfigError(f"{where}: settings: must be a table")
        settings = settings_from_table(doc["settings"], settings, f"{where}: settings")
    exps = []
    raw = doc.get("experiment", [])
    if not isinstance(raw, list) or not raw:
        raise ConfigError(f"{where}: experiment: at least one [[experiment]] table is needed")
    names = set()
    for i, e in enumerate(raw):
        w = f"{where}: experiment[{i}]"
        if not isinstance(e, dict):
            raise ConfigError(f"{w}: must be a table")
        for k in e:
            if k not in ("name", "reference", "duration_s", "seeds", "description"):
                raise ConfigError(
                    f"{w}.{k}: unknown key (known: name, reference, duration_s, seeds, description)"
                )
        name = e.get("name")
        if not isinstance(name, str) or not name or "/" in name or name in names:
            raise ConfigError(f"{w}.name: must be a unique non-empty name without '/'")
        names.add(name)
        if "reference" not in e:
            raise ConfigError(f"{w}.reference: missing")
        ref = parse_reference(str(e["reference"]), f"{w}.reference")
        d = check_duration(e.get("duration_s", dur), f"{w}.duration_s")
        seeds = e.get("seeds", {})
        if not isinstance(seeds, dict):
            raise ConfigError(f"{w}.seeds: must be a table")
        exps.append(Experiment(name, ref, d, seeds))
    return ExperimentSet(
        str(head.get("name", p.stem)),
        list(ctrls),
        exps,
        settings,
        seed,
        rel("model"),
        rel("truth"),
        str(p),
        text,
    )


def run_experiments(
    es: ExperimentSet,
    out_dir: str | Path,
    *,
    force: bool = False,
    model: IdentifiedModel | None = None,
    make_rig: Callable[[], Any],
    report: Callable[[str], None] = print,
    plant: str | None = None,
) -> dict[str, Any]:
    """Run every experiment with every controller; write ``DIR/<name>.h5`` and
    ``DIR/metrics.json``; return the metrics document.

    ``make_rig()`` gives a fresh manipulator per run (every controller starts from the
    same state and noise seed).  ``plant``: the identification the rig's muscle is
    (model in the loop, recorded as the files' root attr ``plant``).  Each file is written while its runs go (a crash leaves
    what was recorded); a run that aborts keeps what it recorded, and the remaining runs
    are not started (their groups stay ``pending``).
    """
    from pmalab.paths import check_output

    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise OutputError(f"{out}: is a file (give a directory)")
    for e in es.experiments:
        check_output(out / f"{e.name}.h5", force)
    check_output(out / "metrics.json", force)
    out.mkdir(parents=True, exist_ok=True)
    doc: dict[str, Any] = {
        "experiments": es.name,
        "file": es.path,
        "controllers": es.controllers,
        "results": [],
    }
    total = len(es.experiments) * len(es.controllers)
    done = 0
    for e in es.experiments:
        stop = False
        planned = [
            (c, planned_attrs(c, e.reference, e.duration_s, es.settings, model))
            for c in es.controllers
        ]
        with ControlRecording(
            out / f"{e.name}.h5",
            planned,
            e.reference.quantity,
            force=force,
            root_attrs={
                "experiment": e.name,
                "experiments_file": es.path,
                "seeds": e.seeds,
                **({"plant": plant} if plant else {}),
            },
        ) as rec:
            for c in es.controllers:
                done += 1
                rig = make_rig()
                w = rec.writer(c)
                with rig:
                    run = run_control(
                        rig, c, e.reference, e.duration_s, es.settings, model, name=c, sink=w
                    )
                w.finish(run)
                m = run_metrics(run)
                doc["results"].append(
                    {
                        "experiment": e.name,
                        "reference": e.reference.text,
                        "controller": c,
                        "status": run.status,
                        "metrics": m,
                        "seeds": e.seeds,
                    }
                )
                report(f"[{done}/{total}] {e.name} {c}: {run.status}; " + metrics_line(m))
                if not run.completed:
                    stop = True
                    break
        if stop:
            break
    (out / "metrics.json").write_text(
        json.dumps(doc, indent=1, allow_nan=False, default=str), encoding="utf-8"
    )
    return doc


def metrics_line(m: Mapping[str, Any]) -> str:
    """One line of a run's metrics."""
    u = m.get("unit", "")

    def f(key: str, fmt: str, unit: str = "") -> str:
        v = m.get(key)
        return (
            "—"
            if v is None or (isinstance(v, float) and not math.isfinite(v))
            else format(v, fmt) + unit
        )

    if m.get("kind") == "square":
        return (
            f"overshoot {f('overshoot_pct', '.1f', ' %')}, rise {f('rise_time_s', '.2f', ' s')}, "
            f"settling {f('settling_time_s', '.2f', ' s')}"
            + ("" if m.get("settled", True) else " (never settles)")
            + f", sse {f('steady_state_error', '.3g', ' ' + u)}, "
            f"RMS {f('rms_error', '.3g', ' ' + u)}"
        )
    return f"RMS {f('rms_error', '.3g', ' ' + u)}, max {f('max_error', '.3g', ' ' + u)}"
