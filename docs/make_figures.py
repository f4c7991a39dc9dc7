"""The documentation's figures, made by the code they document.

loop.png: one held-out run of the tutorial's campaign (a simulated muscle that hides
viscous friction): the measured force-position loop, the Bouc-Wen seed model's prediction
and the prediction once diagnosis added the missing effect.

The documentation build runs this into its cache (``docs/hooks/show.py``; the site shows
``generated/figures/loop.png``).  The README's copy, ``docs/assets/loop.png``, is tracked
and renewed by hand: ``python docs/make_figures.py docs/assets``.

Usage: python docs/make_figures.py OUT_DIR
"""

from __future__ import annotations

import sys
import tempfile
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from pmalab.acquisition.protocol import load_protocol
from pmalab.acquisition.runner import RunnerOptions, run_protocol
from pmalab.identify.api import identify, load, split_roles
from pmalab.paths import RIGS_DIR
from pmalab.rig.loader import load_rig


def loop_figure(out: Path) -> Path:
    work = Path(tempfile.mkdtemp())
    with load_rig(RIGS_DIR / "sim-viscous-friction.toml") as rig:
        run_protocol(rig, load_protocol("diagnosis-test"), work / "c.h5",
                     options=RunnerOptions(progress=False))
    train, held = split_roles(load(work / "c.h5"))
    base = identify(train, "bouc-wen", validate=held)
    better = identify(train, "bouc-wen", effects=["viscous-friction"], validate=held)
    run = next(r for r in held if "2Hz" in r.name)
    steady = run.steady() if hasattr(run, "steady") else run
    keep = np.isin(run.time, steady.time)
    x, f = run.position[keep], run.force[keep]
    fb, fi = base.predict(run)[keep], better.predict(run)[keep]
    nb = np.sqrt(np.mean((f - fb) ** 2)) / np.std(f)
    ni = np.sqrt(np.mean((f - fi) ** 2)) / np.std(f)
    fig, ax = plt.subplots(figsize=(7.0, 4.2), dpi=110)
    ax.plot(x, f, color="0.2", lw=1.6, label="measured (held-out run)")
    ax.plot(x, fb, color="tab:red", lw=1.1, ls="--", label=f"Bouc-Wen seed model (nrmse {nb:.3f})")
    ax.plot(x, fi, color="tab:blue", lw=1.1, label=f"+ viscous friction, found by diagnose (nrmse {ni:.3f})")
    ax.set_xlabel("contraction x (mm)")
    ax.set_ylabel("tension F (N)")
    ax.set_title(f"{run.name}: the error falls {100 * (1 - ni / nb):.0f} % once the missing effect is added",
                 fontsize=10)
    ax.legend(fontsize=8, loc="best")
    ax.grid(alpha=0.3)
    fig.tight_layout()
    out.mkdir(parents=True, exist_ok=True)
    path = out / "loop.png"
    fig.savefig(path)
    return path


if __name__ == "__main__":
    print(loop_figure(Path(sys.argv[1]) if len(sys.argv) > 1 else Path("docs/assets")))
