"""Element laws on muscles they were not written for: held-out error ÷ noise floor per law.

Each case is a simulated muscle whose braid friction has one element law's shape but breaks
an assumption the law's authors might make (truth files under ``data/truth/laws/``: a fixed
play-operator weight profile scaled in magnitude with pressure, other threshold profiles,
slip displacements growing with pressure, fewer or more elements than the law fits), plus
the project's own law-shaped muscles (``data/truth/hysteresis-*.toml``).  The independent
cases are recorded with ``data/protocols/laws-pressure.toml`` (14 identification runs at
seven odd pressures and two odd frequencies, 4 held-out runs between them, 4 N load-cell
noise); the project's own with ``diagnosis-test.toml`` (8 + 2 runs), as before.
``pmalab identify --model bouc-wen,duhem,maxwell-slip,prandtl-ishlinskii`` then ranks the
laws; each cell is the mean over the held-out runs of nrmse ÷ that run's noise floor, with
the pressure structure the matching law chose (and its prior's strength λ when one was kept),
and the matching law's figure with every parameter its own pressure law (``--structure free``, the behaviour before structures were
chosen).  *start state on the whole record*: the matching law's and the first law's figure
when each held-out record's start state and force zero are fitted on the whole record, the
part its error is scored on included — what no rule that estimates them on the early part
can be expected to beat, so the distance to it is what that estimate costs, and a rank that
holds there is not decided by it.  ``python -m bench laws``;
``PMALAB_BENCH_SEEDS=N`` sets the seeds per case (default 2).
"""

from __future__ import annotations

import contextlib
import io
import json
import os
import tempfile
import time
from pathlib import Path

from bench.table import print_table
from pmalab.paths import PROTOCOLS_DIR, TRUTH_DIR

LAWS = ("bouc-wen", "duhem", "maxwell-slip", "prandtl-ishlinskii")
#: the base law a diagnosis starts from here (``diagnose --model bouc-wen``, as in the
#: tutorial and ``bench diagnose``): the other laws are scored against it
BASE = "bouc-wen"
#: (truth file, protocol, the law whose shape it has)
CASES = (
    ("laws/pi-scaled-profile.toml", "laws-pressure.toml", "prandtl-ishlinskii"),
    ("laws/pi-rising-profile.toml", "laws-pressure.toml", "prandtl-ishlinskii"),
    ("laws/ms-slip-growing.toml", "laws-pressure.toml", "maxwell-slip"),
    ("laws/ms-two-elements.toml", "laws-pressure.toml", "maxwell-slip"),
    ("hysteresis-maxwell-slip.toml", "diagnosis-test.toml", "maxwell-slip"),
    ("hysteresis-prandtl-ishlinskii.toml", "diagnosis-test.toml", "prandtl-ishlinskii"),
)


def _cli(argv: list[str]) -> int:
    from pmalab.cli import main as pmalab_main

    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
        return pmalab_main(argv)


def campaign(truth: Path, protocol: Path, seed: int, work: Path) -> Path:
    """Record one simulated campaign (identification + held-out runs in one file)."""
    rig = work / f"rig-{truth.stem}-{seed}.toml"
    rig.write_text(f'[rig]\nkind = "sim"\ntruth = "{truth}"\nseed = {seed}\n')
    out = work / f"{truth.stem}-{seed}.h5"
    assert _cli(["run", "--rig", str(rig), "--protocol", str(protocol), "--out", str(out),
                 "-q"]) == 0
    return out


def laws_table(c: Path, out: Path, laws: tuple[str, ...] = LAWS,
               structure: str = "auto") -> tuple[dict, float]:
    """``identify --model a,b,... --structure S``: ({law: laws.json row}, wall seconds)."""
    t0 = time.perf_counter()
    assert _cli(["identify", str(c), "--model", ",".join(laws), "--out", str(out), "-q",
                 "--jobs", "2", "--structure", structure]) == 0
    wall = time.perf_counter() - t0
    doc = json.loads((out / "laws.json").read_text())
    rows = {r["law"]: dict(r, rank=i + 1, floor=doc["noise_floor_nrmse"])
            for i, r in enumerate(doc["laws"])}
    for law in laws:
        f = out / law / "identification.json"
        if f.exists():
            ps = json.loads(f.read_text()).get("pressure_structure") or {}
            if law in rows:
                chosen = ps.get("chosen", "-")
                lam = ((ps.get("priors") or {}).get(chosen) or {}).get("chosen_strength")
                # the structure, and the strength of its prior when one was kept
                rows[law]["structure"] = chosen + (f" λ{lam:g}" if lam else "")
    return rows, wall


def free_x_floor(c: Path, law: str, floor: float | None) -> float | None:
    """The law's mean held-out nrmse ÷ ``floor`` with ``--structure free``."""
    import numpy as np

    from pmalab.identify.api import identify
    from pmalab.runfile import read_runs

    res = identify(read_runs(c), law, jobs=2, structure="free")
    vn = [float(v.metrics["nrmse"]) for v in res.validation]
    return float(np.mean(vn)) / floor if vn and floor else None


def whole_record_x_floor(c: Path, law: str, floor: float | None) -> float | None:
    """The law's mean held-out nrmse ÷ ``floor`` when each held-out record's record
    parameters (start state, force zero) are fitted on the whole record instead of its early
    part, scored on the same samples as ``identify`` scores (after the early part)."""
    import numpy as np

    from pmalab.identify.api import identify
    from pmalab.identify.estimation.records import estimate_record
    from pmalab.identify.metrics import metrics
    from pmalab.identify.signals import Signals
    from pmalab.runfile import read_runs

    res = identify(read_runs(c), law, jobs=2)
    cf = res.campaign
    vn = []
    for v in res.validation:
        sig, f = Signals.from_run(v.run), np.asarray(v.run.force, dtype=float)
        th = estimate_record(cf.model, sig, f, cf.theta(sig.p_nom), cf.bounds,
                             cf.record_prior())
        i0 = v.scored_from
        vn.append(float(metrics(f[i0:], cf.model.predict(sig, th)[i0:], sig.x[i0:])["nrmse"]))
    return float(np.mean(vn)) / floor if vn and floor else None


def truth_model(truth: Path):
    """The force model that expresses ``truth``'s friction elements exactly: pmalab's
    Maxwell-slip law when the truth has at most its four elements, else
    :func:`bench.elasto_slide.elements_law` with the truth's count (a play-operator muscle:
    an operator of threshold r and weight w is an element of stiffness w and slip
    displacement r).  Returns (model, elements to pass to
    :func:`pmalab.rig.sim.reference.maxwell_slip_theta`)."""
    from bench.elasto_slide import elements_law
    from pmalab.identify.campaign.fit import _as_model
    from pmalab.identify.laws.maxwell_slip import ELEMENTS
    from pmalab.identify.model import ForceModel
    from pmalab.rig.sim.truth import load_truth

    n = len(load_truth(truth).section("friction")["presliding_mm"])
    if n <= ELEMENTS:
        return _as_model("maxwell-slip"), ELEMENTS
    return ForceModel(elements_law(n)), n


def truth_held_out(c: Path, truth: Path) -> list[tuple[str, float]] | None:
    """Each held-out run's (name, nrmse) when the simulated muscle's own parameters predict
    it by the rule ``identify`` predicts it by: the truth at the run's nominal pressure as
    element parameters (:func:`pmalab.rig.sim.reference.maxwell_slip_theta`, the model of
    :func:`truth_model`), the record's start state h0 and force zero estimated on its early
    part (:func:`pmalab.identify.estimation.records.predict_record`), scored from
    :func:`~pmalab.identify.estimation.records.scored_from` on.  None when no element sum
    can express the truth (a hidden effect enabled)."""
    import numpy as np

    from pmalab.identify.api import split_roles
    from pmalab.identify.estimation.records import predict_record, scored_from
    from pmalab.identify.long_records import fit_part
    from pmalab.identify.metrics import metrics
    from pmalab.identify.signals import Signals
    from pmalab.rig.sim.reference import maxwell_slip_theta
    from pmalab.rig.sim.truth import load_truth
    from pmalab.runfile import read_runs

    tr = load_truth(truth)
    model, elements = truth_model(truth)
    _, held = split_roles([fit_part(r.steady()) for r in read_runs(c)])
    out = []
    for r in held:
        th = maxwell_slip_theta(float(r.nominal_pressure), tr, elements)
        if th is None:
            return None
        sig, f = Signals.from_run(r), np.asarray(r.force, dtype=float)
        # the record parameters (start state h0; the zero c0 is the static line's) are
        # estimated on the record's early part, as for a fitted model
        fm = predict_record(model, sig, {**th, **dict.fromkeys(model.record_params, 0.0)},
                            force=f)
        i0 = scored_from(sig)
        out.append((r.name, float(metrics(f[i0:], fm[i0:], sig.x[i0:])["nrmse"])))
    return out


def truth_x_floor(c: Path, truth: Path, floor: float | None) -> float | None:
    """The simulated muscle's own parameters predicting the held-out runs by the rule
    ``identify`` predicts them by (:func:`truth_held_out`: start state and force zero
    estimated on each record's early part, scored on the rest): mean held-out nrmse ÷
    ``floor``.  What a perfect identification would score — of the Maxwell-slip law for a
    muscle of up to four elements, of a law with the truth's own play operators for a
    Prandtl-Ishlinskii-shaped one (whose thresholds sit off the law's grid); None when no
    element sum can express the truth.

    A matching law above its bound where this is above it too misses on the held-out
    scoring (a record's start state and zero taken from its first cycle), not on the fit."""
    import numpy as np

    vn = truth_held_out(c, truth)
    if vn is None:
        return None
    return float(np.mean([v for _, v in vn])) / floor if vn and floor else None


def claim_headroom(base_x_floor: float | None) -> str:
    """The most any other law can gain on the diagnosis's base model, in noise floors, and
    whether that could be claimed: ``diagnose`` claims a law only when the law cuts the
    base model's mean held-out nrmse by ``MIN_GAIN_X_FLOOR`` noise floors, and a law that
    predicts down to the noise floor (× floor ≈ 1, the least any model can reach in
    expectation) gains base − 1.  Below the threshold no law can be named on the campaign,
    however well it predicts."""
    from pmalab.identify.diagnosis.ranking import MIN_GAIN_X_FLOOR

    if base_x_floor is None:
        return "-"
    head = base_x_floor - 1.0
    return f"{head:.2f}" + ("" if head >= MIN_GAIN_X_FLOOR else f" (< {MIN_GAIN_X_FLOOR:g}: none)")


def main() -> None:
    seeds = int(os.environ.get("PMALAB_BENCH_SEEDS", "2"))
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        for truth_name, proto, law in CASES:
            for seed in range(7, 7 + seeds):
                c = campaign(TRUTH_DIR / truth_name, PROTOCOLS_DIR / proto, seed, work)
                res, wall = laws_table(c, work / f"{Path(truth_name).stem}-{seed}")
                first = min(res.values(), key=lambda r: r["rank"])["law"]
                cells = []
                for lw in LAWS:
                    r = res.get(lw, {})
                    x = r.get("x_floor")
                    cells.append("-" if x is None else f"{x:.2f}")
                st = res.get(law, {}).get("structure", "-")
                # the matching law with every parameter its own pressure law (as before the
                # structures): what the choice gained
                xf = free_x_floor(c, law, res[law]["floor"])
                # the matching law's and the first law's figure with each held-out record's
                # start state fitted on the whole record: what its estimate costs
                whole = [whole_record_x_floor(c, lw, res[law]["floor"])
                         for lw in dict.fromkeys((law, first))]
                rows.append((truth_name, seed, law, *cells, st,
                             "-" if xf is None else f"{xf:.2f}",
                             " / ".join("-" if w is None else f"{w:.3f}" for w in whole),
                             "yes" if first == law else f"NO ({first})",
                             claim_headroom(res.get(BASE, {}).get("x_floor")),
                             f"{wall:.1f}"))
    print("held-out nrmse ÷ noise floor (mean over the held-out runs), identify with 4 laws:")
    print_table(("truth (data/truth)", "seed", "matching law", *LAWS, "structure",
                 "matching, free", "start state on the whole record: matching / first",
                 "first", f"most any law can gain on {BASE}", "identify s"), rows)


if __name__ == "__main__":
    main()
