"""Demos: `pmalab demo --hidden X` for every hidden effect — does diagnosis find X?

Each demo records the Bouc-Wen seed campaign on the simulated rig with X hidden, identifies,
diagnoses (running the experiment diagnosis suggests when its ranking is ambiguous: the
seed campaign trains at one frequency, where a viscous force and a sensor delay look
alike), identifies again with what diagnosis named and writes the report.  The table shows
what diagnosis added, its verdict, the active rounds it ran, the validation error fall and
the wall time of the whole demo (a user's wait).
"""

from __future__ import annotations

import contextlib
import io
import json
import tempfile
import time
from pathlib import Path

from bench.table import print_table


def main() -> None:
    from pmalab.cli import main as pmalab_main
    from pmalab.demo import DEMO_EFFECTS

    rows = []
    with tempfile.TemporaryDirectory() as td:
        for hidden in DEMO_EFFECTS:
            out = Path(td) / hidden
            buf = io.StringIO()
            t0 = time.perf_counter()
            with contextlib.redirect_stdout(buf), contextlib.redirect_stderr(buf):
                rc = pmalab_main(["demo", "--hidden", hidden, "--out", str(out), "--quiet"])
            dt = time.perf_counter() - t0
            text = buf.getvalue()
            verdict = next(
                (ln.split("diagnosis:", 1)[1].strip() for ln in text.splitlines()
                 if ln.strip().startswith("diagnosis:")), f"exit {rc}")
            fall = next((ln.strip() for ln in text.splitlines()
                         if ln.strip().startswith("validation error falls")), "")
            d = json.loads((out / "diagnose" / "diagnosis.json").read_text()) if rc == 0 else {}
            added = [s["added"] for s in d.get("ladder", []) if s.get("added")]
            rows.append((hidden, ", ".join(added) or "none", len(d.get("rounds") or [])
                         if (d.get("settings") or {}).get("active") else 0,
                         fall.split("(")[0].replace("validation error falls", "").strip(),
                         "yes" if verdict.startswith("found it") and hidden in added else "NO",
                         round(dt, 1)))
    print_table(["hidden", "ladder added", "active rounds", "error fall", "found", "demo s"],
                rows)
