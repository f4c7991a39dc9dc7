"""Record a campaign on the simulated rig from a truth file, as a user would with ``pmalab run``.

One helper for every test that needs a simulated campaign: a rig file naming the truth and
the sensor seed, then ``pmalab run --protocol … --out … --quiet`` with its output captured.
"""

from __future__ import annotations

import contextlib
import io
from pathlib import Path

from pmalab.cli import main as pmalab_main
from pmalab.paths import PROTOCOLS_DIR, TRUTH_DIR


def noise_free_truth(name: str, work: Path) -> Path:
    """``work/truth.toml``: the shipped truth file ``name`` (relative to the truth folder)
    without sensor noise (load cell and position), the rest as shipped."""
    text = (TRUTH_DIR / name).read_text().replace("force_noise_N = 4.0", "force_noise_N = 0.0")
    assert "force_noise_N = 0.0" in text
    out = work / "truth.toml"
    out.write_text(text + "position_noise_mm = 0.0\n")
    return out


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


def truth_runs(truth: Path, work: Path, seed: int, elements: int = 4):
    """Each steady run of a campaign recorded with ``truth`` and ``seed``
    (:func:`record_campaign`), with its signals and the truth's own parameters at the run's
    nominal pressure as ``elements`` elasto-slide elements
    (:func:`pmalab.rig.sim.reference.maxwell_slip_theta`, start state ``h0`` = 0 N): the
    arguments of ``predict_record(model, signals, theta, force=run.force)``.

    Yields
    ------
    (run, signals, theta)
        Fails the calling test when the law cannot express the truth."""
    from pmalab.identify.signals import Signals
    from pmalab.rig.sim.reference import maxwell_slip_theta
    from pmalab.rig.sim.truth import load_truth
    from pmalab.runfile import read_runs

    tr = load_truth(truth)
    for run in read_runs(record_campaign(truth, work, seed)):
        r = run.steady()
        th = maxwell_slip_theta(float(r.nominal_pressure), tr, elements)
        assert th is not None, r.name
        yield r, Signals.from_run(r), {**th, "h0": 0.0}
