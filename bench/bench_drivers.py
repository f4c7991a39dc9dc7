"""Drivers: Modbus block-read rate and jitter, TCP loopback and RTU on a pty (goal TCP >= 1 kHz)

Each transport talks to ``pmalab emulate`` running in its own process (as a user runs it),
so client and emulator do not share an interpreter.  ``read`` columns time N block reads
back to back (one FC3/FC4 request carrying all four analog inputs); ``cycle`` adds the
regulator write the runner makes every sample (what the rate probe judges); ``paced 500 Hz``
runs the runner's loop (absolute deadlines on the real clock, read + write per deadline)
for 2 s and reports the achieved period's standard deviation and the deadlines missed.
"""

from __future__ import annotations

import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from bench.table import print_table
from pmalab.paths import RIGS_DIR
from pmalab.rig.base import RealClock
from pmalab.rig.drivers.rigfile import build_modbus_rig, read_modbus_rig_file
from pmalab.rig.emulators.launcher import free_tcp_port

N_READS = 2000
PACED_S = 2.0


def start_emulate(rig_file: Path, extra: list[str]) -> subprocess.Popen:
    proc = subprocess.Popen(
        [sys.executable, "-m", "pmalab.cli", "emulate", "--rig", str(rig_file), *extra],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
    )  # fmt: skip
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline:
        line = proc.stdout.readline()
        if "Ctrl-C to stop" in line:
            return proc
        if not line and proc.poll() is not None:
            break
    proc.kill()
    raise RuntimeError(f"pmalab emulate --rig {rig_file} did not start")


def measure(spec, label: str, n: int) -> list[object]:
    spec.probe_samples = 0
    with build_modbus_rig(spec) as rig:
        s = rig.sampler
        companion, s.probe_companion = s.probe_companion, None
        reads = s.probe_rate(n)
        s.probe_companion = companion
        probe = s.probe_rate(n)
        # paced loop at 500 Hz, absolute deadlines, as the runner does it
        clock = RealClock()
        dt = 1 / 500
        t0 = clock.now() + 0.01
        stamps = []
        k = missed = 0
        while k * dt < PACED_S:
            clock.sleep_until(t0 + k * dt)
            stamps.append(s.read_block().time[0])
            rig.cylinder_regulator.set_pressure(0.0)
            k += 1
            lag = clock.now() - (t0 + k * dt)
            if lag > dt:
                skip = int(lag / dt)
                missed += skip
                k += skip
        periods = np.diff(stamps) * 1e3
        total = len(stamps) + missed
        return [
            label,
            n,
            reads.p50_ms,
            reads.p99_ms,
            reads.jitter_ms,
            round(reads.max_rate_Hz),
            probe.p50_ms,
            float(np.std(periods)),
            f"{100 * missed / total:.1f} %",
            "yes" if probe.sustainable_Hz >= 500 else f"no ({probe.sustainable_Hz:.0f} Hz)",
        ]


def main() -> None:
    rows = []
    port = free_tcp_port()
    proc = start_emulate(RIGS_DIR / "labjack-t7.toml", ["--port", str(port)])
    try:
        spec = read_modbus_rig_file(RIGS_DIR / "labjack-t7.toml")
        spec.transport.port = port
        rows.append(measure(spec, "Modbus TCP loopback (T7 map, FLOAT32 x4)", N_READS))
    finally:
        proc.terminate()
        proc.communicate(timeout=20)

    with tempfile.TemporaryDirectory() as tmp:
        rtu_toml = Path(tmp) / "rtu.toml"
        link = Path(tmp) / "modbus-rtu"
        text = (RIGS_DIR / "generic-modbus-rtu.toml").read_text()
        rtu_toml.write_text(text.replace("/tmp/pmalab-emulator/modbus-rtu", str(link)))
        for label, extra, n in (
            ("Modbus RTU pty, paced 115200 baud (INT16 x4)", [], 300),
            ("Modbus RTU pty, unpaced (pty speed)", ["--no-baud-pacing"], 1000),
        ):
            proc = start_emulate(rtu_toml, extra)
            try:
                rows.append(measure(read_modbus_rig_file(rtu_toml), label, n))
            finally:
                proc.terminate()
                proc.communicate(timeout=20)

    print_table(
        ["transport", "n", "read p50 ms", "read p99 ms", "read sd ms", "reads/s",
         "cycle p50 ms", "paced 500 Hz: period sd ms", "missed", "sustains 500 Hz"],
        rows,
    )  # fmt: skip


if __name__ == "__main__":
    main()
