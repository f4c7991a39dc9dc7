"""Forward model: the Bouc-Wen benchmark (Noël & Schoukens 2016) and pmalab simulate's speed."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault(
    "NUMBA_CACHE_DIR", os.path.join(os.path.dirname(__file__), "..", ".venv", "numba-cache")
)

import numpy as np

from bench.table import print_table
from pmalab.rig.sim import bouc_wen_benchmark as bwb
from pmalab.runfile import Run, write_runs

GOAL_M = 1.0e-5
GOAL_SIM_S = 0.5
PMALAB = [str(Path(sys.executable).with_name("pmalab"))]


def _shell(args: list[str]) -> float:
    t0 = time.perf_counter()
    subprocess.run(PMALAB + args, check=True, capture_output=True, text=True)
    return time.perf_counter() - t0


def main() -> None:
    with tempfile.TemporaryDirectory() as d:
        root = Path(d)
        t_gen = _shell(["benchmark", "bouc-wen", "--out", str(root / "data")])
        t_id = _shell(["identify", str(root / "data/train.h5"), "--output", "position",
                       "--model", "bouc-wen", "--add", "inertia", "--add", "viscous-friction",
                       "--validate", str(root / "data/test-multisine.h5"),
                       str(root / "data/test-sweep.h5"), "--out", str(root / "oe")])
        doc = json.loads((root / "oe/identification.json").read_text())
        rows = {v["run"]: v for v in doc["validation"]}
        n_par = len([n for n in doc["parameter_names"]
                     if n not in doc["runs"][0]["fixed"] and n != "h0"])
        ms = rows["multisine-test"]["rmse_position_m"]
        sw = rows["sweep-test"]["rmse_position_m"]
        table = [(name, f"{err:.2g}", str(n) if n else "-", "")
                 for name, err, n in bwb.PUBLISHED_RESULTS]
        table.append(("pmalab: bouc-wen + inertia + viscous-friction (output error)",
                      f"{ms:.2g}", str(n_par),
                      f"sweep {sw:.2g} m; goal <= {GOAL_M:g} m: "
                      + ("met" if ms <= GOAL_M else "MISSED")))
        print_table(["model", "rms error multisine test (m)", "parameters", "note"], table)
        q = {n: v[0] for n, v in doc["pressure_fits"].items()}
        print_table(["parameter", "true", "identified", "error %"],
                    [(n, f"{bwb.AS_PMALAB[n]:g}", f"{q[n]:.5g}",
                      f"{100 * (q[n] - bwb.AS_PMALAB[n]) / bwb.AS_PMALAB[n]:+.2f}")
                     for n in ("k", "A", "beta", "gamma", "inertia_m", "visc_c")])

        # pmalab simulate: a 60 s, 500 Hz force record through the identified model
        t = np.arange(30000) / 500.0
        u = 40.0 * np.sin(2 * np.pi * 2.0 * t) + 20.0 * np.sin(2 * np.pi * 7.0 * t)
        x = np.zeros_like(t)
        write_runs(root / "in60.h5", [Run("in60", t, x, u, np.zeros_like(t),
                                          attrs={"muscle_pressure_MPa": 0.0,
                                                 "frequency_Hz": 7.0, "waveform": "sine"})])
        t_cli = _shell(["simulate", str(root / "oe"), str(root / "in60.h5"), "--out",
                        str(root / "sim60.h5")])
        from pmalab.identify.forward import IdentifiedPlant, simulate

        plant = IdentifiedPlant.read(root / "oe")
        simulate(plant.model, plant.theta(0.0), t[:100], u[:100], 0.0)
        t0 = time.perf_counter()
        s = simulate(plant.model, plant.theta(0.0), t, u, 0.0)
        t_int = time.perf_counter() - t0
        print_table(["what a user waits for", "s", "goal s"], [
            ("pmalab benchmark bouc-wen (3 files, RK4 at 15 kHz)", f"{t_gen:.2f}", ""),
            ("pmalab identify --output position (train + 2 tests, from the shell)", f"{t_id:.2f}", ""),
            ("pmalab simulate, 60 s at 500 Hz, from the shell (start-up, state estimate)",
             f"{t_cli:.2f}", ""),
            (f"forward integration alone, 60 s at 500 Hz ({s.n_sub} sub-steps/sample)",
             f"{t_int:.3f}", f"{GOAL_SIM_S:g}"),
        ])
