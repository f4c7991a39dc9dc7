"""Record a campaign on the simulated rig from a truth file, as a user would with ``pmalab run``.

One helper for every test that needs a simulated campaign: a rig file naming the truth and
the sensor seed, then ``pmalab run --protocol … --out … --quiet`` with its output captured.
"""

from __future__ import annotations

import contextlib
import io
from pathlib import Path

from pmalab.cli import main as pmalab_main
from pmalab.paths import PROTOCOLS_DIR


def record_campaign(truth: Path, work: Path, seed: int,
                    protocol: Path = PROTOCOLS_DIR / "diagnosis-test.toml",
                    name: str = "campaign.h5") -> Path:
    """The run file ``work/name`` recorded on a simulated rig with ``truth`` and ``seed``.

    Fails the calling test (with ``pmalab run``'s output) when the recording fails."""
    work.mkdir(parents=True, exist_ok=True)
    rig = work / f"rig-{Path(name).stem}.toml"
    rig.write_text(f'[rig]\nkind = "sim"\ntruth = "{Path(truth).resolve()}"\nseed = {seed}\n')
    out = work / name
    text = io.StringIO()
    with contextlib.redirect_stdout(text), contextlib.redirect_stderr(text):
        rc = pmalab_main(["run", "--rig", str(rig), "--protocol", str(protocol),
                          "--out", str(out), "--quiet"])
    assert rc == 0, text.getvalue()
    return out
