"""NI-DAQmx backend at 10 kHz against the strict fake: no overflow, exact spacing, safe aborts.

The fake (tests/fake_nidaqmx) generates the device's samples as fast as they are read (the
simulated muscle behind it), so this measures what the recording side costs per sample at
10 kHz: wall time against the recording's own length (must stay below 1 for a real card
not to overflow), the recorder's CPU share, the spacing of the time stamps, missed scans;
then an injected overflow and a device removal, each ending in a safe abort with the
samples kept.  ``PMALAB_BENCH_NI_S`` sets the recording length (default 60 s).
"""

from __future__ import annotations

import os
import resource
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from bench.table import print_table

ROOT = Path(__file__).resolve().parents[1]
WIRING_AI = {"ai0": ("muscle_pressure", 4.0, 1.0), "ai1": ("cylinder_pressure", 4.0, 1.0),
             "ai2": ("position", 0.2, 2.0), "ai3": ("force", 1 / 250, 0.0)}
WIRING_AO = {"ao0": ("cylinder", 0.09, 0.0), "ao1": ("muscle", 0.09, 0.0)}


def _protocol(seconds: float, rate: float) -> str:
    cycles = max(1, int(seconds * 0.5) - 2)
    return (f'[protocol]\nname = "ni-bench"\nsample_rate_Hz = {rate}\n[[run]]\nname = "r"\n'
            f'muscle_pressure_MPa = 0.4\nwaveform = "sine"\nfrequency_Hz = 0.5\n'
            f'magnitude_MPa = 0.3\ncycles = {cycles}\nramp_s = 1.0\nsettle_s = 0.5\n')


def main() -> None:
    sys.path.insert(0, str(ROOT / "tests" / "fake_nidaqmx"))
    from nidaqmx import _device

    from pmalab.acquisition.protocol import parse_protocol
    from pmalab.acquisition.runner import RunnerOptions, run_protocol
    from pmalab.errors import SafetyAbort
    from pmalab.paths import RIGS_DIR
    from pmalab.rig.loader import load_rig
    from pmalab.rig.sim.physics import RigPhysics
    from pmalab.runfile import read_runs

    seconds = float(os.environ.get("PMALAB_BENCH_NI_S", "60"))
    rows = []
    with tempfile.TemporaryDirectory() as td:
        for case in ("clean", "overflow", "removed"):
            dev = _device.install(_device.FakeDevice("Dev1", RigPhysics(None, seed=1),
                                                     WIRING_AI, WIRING_AO))
            rate = 10_000.0
            proto = parse_protocol(_protocol(seconds if case == "clean" else 6.0, rate))
            if case != "clean":
                dev.inject(case, at_sample=int(3.0 * rate))
            out = Path(td) / f"{case}.h5"
            rig = load_rig(RIGS_DIR / "nidaqmx.toml")
            c0 = resource.getrusage(resource.RUSAGE_SELF)
            t0 = time.perf_counter()
            outcome = "completed"
            try:
                run_protocol(rig, proto, out, options=RunnerOptions(progress=False))
            except SafetyAbort as exc:
                text = str(exc)
                code = "-200279" if case == "overflow" else "-201003"
                outcome = ("safe abort, " + ("vents confirmed" if "vented (confirmed" in text
                                             else "vents FAILED (device gone)")
                           + (f", DAQmx {code} named" if code in text else ", CODE MISSING"))
            finally:
                rig.close()
            wall = time.perf_counter() - t0
            c1 = resource.getrusage(resource.RUSAGE_SELF)
            cpu = (c1.ru_utime - c0.ru_utime) + (c1.ru_stime - c0.ru_stime)
            (r,) = read_runs(out)
            dt = np.diff(r.time)
            rec_s = float(r.time[-1] - r.time[0])
            missed = int(r.attrs.get("timing", {}).get("missed", 0))
            rows.append([case, f"{rate:g}", len(r), round(rec_s, 1), round(wall, 1),
                         round(wall / max(rec_s, 1e-9), 2), round(100 * cpu / max(rec_s, 1e-9), 1),
                         f"{np.ptp(dt):.1e}", missed, outcome])
            _device.uninstall()
    print_table(["case", "rate Hz", "samples kept", "recorded s", "wall s", "wall / recorded",
                 "CPU % of one core (per recorded s)", "spacing spread s", "missed", "outcome"],
                rows)
