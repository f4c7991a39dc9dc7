"""Inverse-hysteresis feedforward: 20 mm sine tracking with and without, per controller."""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
from pathlib import Path

os.environ.setdefault(
    "NUMBA_CACHE_DIR", os.path.join(os.path.dirname(__file__), "..", ".venv", "numba-cache")
)

from bench.table import print_table
from pmalab.paths import DATA_DIR

PMALAB = str(Path(sys.executable).with_name("pmalab"))
#: plants whose hysteresis is not the controller model's law (Bouc-Wen, the shipped
#: identification): the default truth (Maxwell-slip braid friction) and a
#: Maxwell-slip-shaped muscle; and the identified model itself in the loop
PLANTS = (("simulated manipulator, default truth", ["--truth", str(DATA_DIR / "truth" / "default.toml")]),
          ("simulated manipulator, Maxwell-slip muscle",
           ["--truth", str(DATA_DIR / "truth" / "hysteresis-maxwell-slip.toml")]))


def _rms(args: list[str], out: Path) -> float:
    p = subprocess.run([PMALAB, "control", "--reference", "sine:0.2Hz:20mm", "--duration",
                        "20", "--out", str(out), "--force", *args], check=True,
                       capture_output=True, text=True)
    line = p.stdout.strip().splitlines()[-1]
    return float(line.split("RMS")[1].split("mm")[0])


def main() -> None:
    rows = []
    with tempfile.TemporaryDirectory() as d:
        for plant, extra in PLANTS:
            for c in ("pid", "sn-pid", "rbf-pid"):
                on = _rms(["--controller", c, "--hysteresis-compensation", "on", *extra],
                          Path(d) / "on.h5")
                off = _rms(["--controller", c, "--hysteresis-compensation", "off", *extra],
                           Path(d) / "off.h5")
                rows.append((plant, c, f"{off:.2f}", f"{on:.2f}",
                             f"{100 * (on - off) / off:+.0f} %"))
    print_table(["plant (model: shipped Bouc-Wen identification)", "controller",
                 "RMS without (mm)", "RMS with (mm)", "change"], rows)
