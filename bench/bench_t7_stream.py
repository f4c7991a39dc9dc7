"""LabJack T7 stream mode against the emulator, real time: 1 kHz for 60 s and 5 kHz for 10 s.

The emulator (``pmalab emulate``) runs in its own process; ``pmalab run`` records through
the Modbus TCP link in another.  Reported per case: scans recorded, missed (gaps), the
spacing of the time stamps, and the recording process's CPU share of one core (its own
user + system time over the recording's length).  ``PMALAB_BENCH_T7_S`` shortens the 1 kHz
case.
"""

from __future__ import annotations

import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from bench.table import print_table


def _protocol(path: Path, rate: float, seconds: float) -> Path:
    cycles = max(1, int(seconds * 0.5) - 2)
    path.write_text(f'[protocol]\nname = "t7-bench"\nsample_rate_Hz = {rate}\n[[run]]\n'
                    f'name = "r"\nmuscle_pressure_MPa = 0.4\nwaveform = "sine"\n'
                    f'frequency_Hz = 0.5\nmagnitude_MPa = 0.3\ncycles = {cycles}\n'
                    f'ramp_s = 1.0\nsettle_s = 0.5\n')
    return path


def main() -> None:
    from pmalab.paths import RIGS_DIR
    from pmalab.rig.emulators.launcher import free_tcp_port
    from pmalab.runfile import read_runs

    rig = RIGS_DIR / "labjack-t7-stream.toml"
    long_s = float(os.environ.get("PMALAB_BENCH_T7_S", "60"))
    rows = []
    with tempfile.TemporaryDirectory() as td:
        for rate, seconds in ((1000.0, long_s), (5000.0, 10.0)):
            port = free_tcp_port()
            emu = subprocess.Popen([sys.executable, "-m", "pmalab.cli", "emulate", "--rig",
                                    str(rig), "--port", str(port)], stdout=subprocess.PIPE,
                                   stderr=subprocess.STDOUT, text=True)
            try:
                while "Ctrl-C to stop" not in emu.stdout.readline():
                    pass
                proto = _protocol(Path(td) / f"p{rate:g}.toml", rate, seconds)
                out = Path(td) / f"r{rate:g}.h5"
                c0 = resource.getrusage(resource.RUSAGE_CHILDREN)
                t0 = time.perf_counter()
                p = subprocess.run([sys.executable, "-m", "pmalab.cli", "run", "--rig", str(rig),
                                    "--port", str(port), "--protocol", str(proto), "--out",
                                    str(out), "--quiet"], capture_output=True, text=True)
                wall = time.perf_counter() - t0
                c1 = resource.getrusage(resource.RUSAGE_CHILDREN)
            finally:
                emu.terminate()
                emu.wait(10)
            if p.returncode != 0:
                rows.append([f"{rate:g}", "-", "-", "-", "-", "-", p.stderr.strip()[-120:]])
                continue
            (r,) = read_runs(out)
            rec = float(r.time[-1] - r.time[0])
            cpu = (c1.ru_utime - c0.ru_utime) + (c1.ru_stime - c0.ru_stime)
            dt = np.diff(r.time)
            rows.append([f"{rate:g}", len(r), round(rec, 1), int(r.attrs["timing"]["missed"]),
                         f"{np.ptp(dt):.1e}", round(100 * cpu / rec, 1),
                         f"wall {wall:.1f} s incl. start-up"])
    print_table(["rate Hz", "scans", "recorded s", "missed", "spacing spread s",
                 "recorder CPU % of a core", ""], rows)
