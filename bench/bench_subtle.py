"""Subtle hidden effects (2–4× the noise floor): identify base / --add EFFECT / diagnose verdict.

For every truth file of ``data/truth/subtle/`` the simulated rig records the small
``diagnosis-test`` campaign; its validation runs (role ``validation``) go to a separate file
that both ``pmalab identify --validate`` and ``pmalab diagnose --validate`` are given.  The
table shows each model's mean validation nrmse as a multiple of the noise floor estimated
from the validation records themselves (:func:`pmalab.identify.noise.noise_floor_nrmse`
on each run's steady window), and what ``pmalab diagnose`` names first and whether it
calls it significant.  Issue 10's goal: base 2–4× the floor, ``--add`` back to ≈ 1×, and
diagnose naming the effect and marking it significant.

``python -m bench subtle`` runs it; ``python -m bench.bench_subtle --no-diagnose`` skips the
(slowest) diagnose step.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from bench.table import print_table

PROTOCOL = "diagnosis-test"
SEED = 5
MODEL = "bouc-wen"


@dataclass
class Case:
    """One subtle truth file and what ``identify --add`` should add for it."""

    name: str  # file stem in data/truth/subtle/
    effects: tuple[str, ...]  # effect ids to --add (empty: clean)


CASES = [
    Case("clean", ()),
    Case("viscous-friction", ("viscous-friction",)),
    Case("asymmetric-hysteresis", ("asymmetric-hysteresis",)),
    Case("nonlinear-stiffness", ("nonlinear-stiffness",)),
    Case("pressure-variation", ("pressure-variation",)),
    Case("sensor-delay", ("sensor-delay",)),
    Case("inertia", ("inertia",)),
    Case("sensor-drift", ("sensor-drift",)),  # tared at each run's start
    Case("sensor-drift-carried", ("sensor-drift",)),  # a between-run offset only: not claimed
    Case("two-effects", ("viscous-friction", "asymmetric-hysteresis")),
    # each alone ≈ 1 floor: base ≈ 4.7× (errors add in quadrature), all three ≈ 1.4×
    Case("three-modest-effects", ("asymmetric-hysteresis", "nonlinear-stiffness", "sensor-delay")),
]


def _cli(args: list[str]) -> None:
    """``pmalab ARGS`` in this process, its chatter swallowed; raises on a non-zero exit."""
    from pmalab.cli import main as pmalab_main

    buf = io.StringIO()
    with contextlib.redirect_stdout(buf), contextlib.redirect_stderr(buf):
        rc = pmalab_main(args)
    if rc != 0:
        raise RuntimeError(f"pmalab {' '.join(args)} -> exit {rc}: {buf.getvalue()[-400:]}")


def record(truth: Path, work: Path, seed: int = SEED, protocol: str = PROTOCOL) -> tuple[Path, Path]:
    """Record the campaign on a simulated rig with ``truth``; (identification, validation) files."""
    from pmalab.runfile import read_runs, write_runs

    rig = work / "rig.toml"
    rig.write_text(f'[rig]\nkind = "sim"\ntruth = "{truth.resolve()}"\nseed = {seed}\n')
    both = work / "campaign.h5"
    _cli(["run", "--rig", str(rig), "--protocol", protocol, "--out", str(both), "--quiet"])
    runs = read_runs(both)
    val = [r for r in runs if r.attrs.get("role") == "validation"]
    ident = [r for r in runs if r.attrs.get("role") != "validation"]
    return write_runs(work / "ident.h5", ident), write_runs(work / "val.h5", val)


def floors(val_file: Path) -> dict[str, float]:
    """Noise-floor nrmse of each validation run (steady window, as identify scores it)."""
    from pmalab.identify.noise import noise_floor_nrmse
    from pmalab.runfile import read_runs

    return {r.name: noise_floor_nrmse(r.steady().force, r.steady().time)
            for r in read_runs(val_file)}


def identify_nrmse(ident: Path, val: Path, out: Path, effects: tuple[str, ...] = ()) -> dict[str, float]:
    """``pmalab identify --validate``: validation nrmse per run."""
    args = ["identify", str(ident), "--model", MODEL, "--validate", str(val), "--out", str(out),
            "--quiet", "--jobs", "1"]
    for e in effects:
        args += ["--add", e]
    _cli(args)
    doc = json.loads((out / "identification.json").read_text())
    return {v["run"]: float(v["nrmse"]) for v in doc["validation"]}


def diagnose_verdict(ident: Path, val: Path, out: Path) -> tuple[str, bool, float, float, str]:
    """``pmalab diagnose --validate``: (top-1 effect, significant?, nrmse before, after,
    the effects it calls ambiguous with it)."""
    _cli(["diagnose", str(ident), "--model", MODEL, "--validate", str(val), "--out", str(out),
          "--quiet", "--jobs", "1", "--max-steps", "2"])
    doc = json.loads((out / "diagnosis.json").read_text())
    top = doc["ranking"][0]
    # nrmse_before/after are null when no held-out run was left to judge on
    def num(v: float | None) -> float:
        return float("nan") if v is None else float(v)

    return (top["effect"], bool(top["significant"]), num(top["nrmse_before"]),
            num(top["nrmse_after"]), ", ".join(e for e in doc.get("ambiguous", [])
                                                 if e != top["effect"]) or "—")


def ratio(nrmse: dict[str, float], floor: dict[str, float]) -> float:
    """Mean over the validation runs of nrmse / that run's noise floor."""
    return float(np.mean([nrmse[k] / floor[k] for k in floor]))


def measure(case: Case, work: Path, *, diagnose: bool = True, truth_dir: Path | None = None,
            seed: int = SEED) -> dict[str, object]:
    """Record, identify (base and with the effects), optionally diagnose one case."""
    from pmalab.paths import TRUTH_DIR

    truth = (truth_dir or TRUTH_DIR / "subtle") / f"{case.name}.toml"
    work.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    ident, val = record(truth, work, seed)
    t_rec = time.perf_counter() - t0
    fl = floors(val)
    t0 = time.perf_counter()
    base = identify_nrmse(ident, val, work / "base")
    t_id = time.perf_counter() - t0
    row: dict[str, object] = {
        "case": case.name, "floor": float(np.mean(list(fl.values()))),
        "base": ratio(base, fl), "added": None, "t_record": t_rec, "t_identify": t_id,
    }
    if case.effects:
        row["added"] = ratio(identify_nrmse(ident, val, work / "added", case.effects), fl)
    if diagnose:
        t0 = time.perf_counter()
        row["diagnose"] = diagnose_verdict(ident, val, work / "diag")
        row["t_diagnose"] = time.perf_counter() - t0
    return row


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(prog="bench_subtle")
    ap.add_argument("--no-diagnose", action="store_true")
    ap.add_argument("--only", nargs="*", default=None, help="case names")
    ap.add_argument("--seed", type=int, default=SEED)
    a = ap.parse_args(argv or [])
    rows = []
    with tempfile.TemporaryDirectory() as td:
        for case in CASES:
            if a.only and case.name not in a.only:
                continue
            r = measure(case, Path(td) / case.name, diagnose=not a.no_diagnose, seed=a.seed)
            d = r.get("diagnose")
            rows.append((
                case.name, r["floor"], f"{r['base']:.2f}×",
                "—" if r["added"] is None else f"{r['added']:.2f}×",
                "—" if d is None else d[0], "—" if d is None else ("yes" if d[1] else "no"),
                "—" if d is None else f"{100 * (1 - d[3] / d[2]):.0f} %",
                "—" if d is None else d[4],
                r["t_record"], r["t_identify"], r.get("t_diagnose", "—"),
            ))
            print(f"   {case.name}: done", flush=True)
    print_table(("truth (data/truth/subtle)", "floor nrmse", "base / floor", "--add / floor",
                 "diagnose top-1", "significant", "diagnose fall", "ambiguous with", "record s", "identify s",
                 "diagnose s"), rows)


if __name__ == "__main__":
    import sys

    main(sys.argv[1:])
