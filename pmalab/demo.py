"""``pmalab demo``: the whole chain on the simulated rig, as a user would type it.

1. record the Bouc-Wen seed campaign on a simulated rig with a *hidden* effect
   (``data/rigs/sim-<effect>.toml``: the user is not told which);
2. identify the base model per pressure level, fit the pressure quadratics, validate;
3. diagnose: where the base model fails, which effect is missing, the ladder; when the
   ranking is ambiguous (the seed campaign trains at one frequency, so a viscous force and
   a sensor delay look alike), run the experiment diagnosis suggests on the rig (active
   identification: ``diagnose --rig --run-suggested``), which appends its runs to the
   campaign, and identify the base model again on the same runs;
4. identify again with the effect diagnosis named and watch the validation error fall;
5. render the PDF report.

Each step is the ``pmalab`` verb a user would run (printed before it runs), so the demo
doubles as a tutorial.
"""

from __future__ import annotations

import argparse
import json
import re
import shutil
import time
from pathlib import Path

from pmalab.arguments import seed as seed_arg
from pmalab.console import add_verbosity
from pmalab.errors import OutputError, OutputExistsError, PmalabError
from pmalab.paths import PROTOCOLS_DIR, RIGS_DIR, TRUTH_DIR

#: hidden effects a demo can use (each has data/rigs/sim-<id>.toml)
DEMO_EFFECTS = (
    "asymmetric-hysteresis",
    "viscous-friction",
    "nonlinear-stiffness",
    "pressure-variation",
    "sensor-delay",
    "inertia",
    "sensor-drift",
)


#: what a demo writes into --out (all that --force may delete)
DEMO_OUTPUTS = frozenset(
    {
        "rig",
        "campaign.h5",
        "identify",
        "diagnose",
        "identify-improved",
        "report.pdf",
        "report.pdf.part",
    }
)


def _demo_output(name: str) -> bool:
    """A file the demo writes (the active rounds' run files are campaign-roundN.h5)."""
    return name in DEMO_OUTPUTS or re.fullmatch(r"campaign-round\d+\.h5", name) is not None


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "demo",
        help="simulated campaign with a hidden effect -> identify -> diagnose -> PDF",
        description="Run the whole chain on the simulated rig and print where the PDF is.",
    )
    p.add_argument("--out", default="demo-output", help="output directory (default demo-output)")
    p.add_argument("--force", action="store_true", help="replace an existing output directory")
    p.add_argument("--model", default="bouc-wen", choices=("bouc-wen", "duhem"))
    p.add_argument(
        "--hidden",
        default="asymmetric-hysteresis",
        choices=DEMO_EFFECTS,
        help="the effect switched on in the simulated muscle (default: "
        "asymmetric-hysteresis, which the Bouc-Wen seed paper reports missing)",
    )
    p.add_argument("--seed", type=seed_arg, default=7, help="random seed of the simulated rig")
    add_verbosity(p, quiet_help="pass -q to every step: results and warnings only")
    p.set_defaults(func=run_demo)


def _step(n: int | str, title: str, argv: list[str]) -> None:
    from pmalab.cli import main

    print(f"\n[{n}/5] {title}\n      $ pmalab {' '.join(argv)}", flush=True)
    t0 = time.perf_counter()
    code = main(argv)
    if code != 0:
        raise PmalabError(f"step {n} ({title}) failed with exit code {code}")
    print(f"      ({time.perf_counter() - t0:.1f} s)", flush=True)


def _error_fall(base: Path, improved: Path):
    """The one error-fall figure (:func:`pmalab.identify.headline.error_fall`): the report's
    base-vs-improved pages print the same."""
    from pmalab.identify.headline import error_fall

    docs = [json.loads((d / "identification.json").read_text()) for d in (base, improved)]
    fall = error_fall(*docs)
    if fall is None:
        raise PmalabError(f"{base}/identification.json: no validation runs")
    return fall


def _neutral_rig(folder: Path, hidden: str) -> Path:
    """Copy the simulated rig and its truth file under neutral names.

    The shipped files are named after their effect; the demo's point is that the user does
    not know it, so neither the file names nor the report's provenance page may tell.
    """
    src = RIGS_DIR / f"sim-{hidden}.toml"
    folder.mkdir(parents=True)
    truth = TRUTH_DIR / f"hidden-{hidden}.toml"
    (folder / "muscle.toml").write_text(truth.read_text())
    text = src.read_text()
    lines = [ln for ln in text.splitlines() if not ln.lstrip().startswith("#")]
    out_lines = ['truth = "muscle.toml"' if ln.strip().startswith("truth") else ln for ln in lines]
    rig = folder / "rig.toml"
    rig.write_text("# simulated DMSP-20 test rig (pmalab demo)\n" + "\n".join(out_lines) + "\n")
    return rig


def _verdict(hidden: str, found: list[str], diag: dict) -> str:
    """One honest sentence on what diagnosis concluded about the hidden effect."""
    ambiguous = diag.get("ambiguous") or []
    from pmalab.reports.figures_active import has_active_rounds

    # active rounds (diagnose --run-suggested); otherwise "rounds" are the ladder's
    rounds = (diag.get("rounds") or []) if has_active_rounds(diag) else []
    if hidden in found and rounds:
        rig_s = sum(float(r.get("rig_time_s") or 0.0) for r in rounds)
        return (
            f"found it, after {len(rounds)} experiment round(s) diagnosis designed and ran "
            f"on the rig ({rig_s:.0f} s of rig time) to separate look-alikes"
        )
    if hidden in found:
        return "found it"
    if hidden in ambiguous:
        return (
            f"found it among look-alikes ({', '.join(ambiguous)}); to separate them: "
            f"{diag.get('suggested_experiment', '')}"
        )
    if not found:
        return (
            "claimed no effect: on this campaign the hidden effect is too small to "
            "matter (inertia, for one, needs tests at ≥ 1–2 Hz)"
        )
    return f"did NOT find it (named {', '.join(found)} instead)"


def run_demo(args: argparse.Namespace) -> int:
    out = Path(args.out)
    if out.exists():
        if not args.force:
            raise OutputExistsError(f"{out}: already exists (use --force to replace it)")
        if not out.is_dir():
            raise OutputError(f"{out}: is not a directory (give a directory for --out)")
        foreign = sorted(p.name for p in out.iterdir() if not _demo_output(p.name))
        if foreign:  # --force replaces a demo's output, never a directory of other work
            shown = ", ".join(foreign[:3]) + (
                f" and {len(foreign) - 3} more" if len(foreign) > 3 else ""
            )
            raise OutputError(
                f"{out}: holds files the demo did not write ({shown}); --force "
                "replaces only a demo output directory: give another --out"
            )
        shutil.rmtree(out)
    out.mkdir(parents=True)
    t0 = time.perf_counter()
    rig = _neutral_rig(out / "rig", args.hidden)
    protocol = PROTOCOLS_DIR / "seed-bouc-wen.toml"
    campaign = out / "campaign.h5"
    base, diagnosis, improved = out / "identify", out / "diagnose", out / "identify-improved"
    q = ["--quiet"] if args.quiet else (["--verbose"] if args.verbose else [])

    _step(
        1,
        "record the seed campaign on a simulated rig with a hidden effect",
        [
            "run",
            "--rig",
            str(rig),
            "--protocol",
            str(protocol),
            "--out",
            str(campaign),
            "--seed",
            str(args.seed),
            "--quiet",
        ],
    )
    _step(
        2,
        f"identify {args.model} per pressure level, quadratics, validation",
        ["identify", str(campaign), "--model", args.model, "--out", str(base), *q],
    )
    _step(
        3,
        "diagnose: where does the model fail, which effect is missing?",
        ["diagnose", str(campaign), "--model", args.model, "--out", str(diagnosis), *q],
    )
    diag = json.loads((diagnosis / "diagnosis.json").read_text())
    if diag.get("ambiguous"):
        _step(
            "3b",
            f"ambiguous ({', '.join(diag['ambiguous'])}): run the experiment diagnosis "
            "suggests on the rig and diagnose again",
            [
                "diagnose",
                str(campaign),
                "--model",
                args.model,
                "--rig",
                str(rig),
                "--run-suggested",
                "--yes",
                "--out",
                str(diagnosis),
                "--force",
                *q,
            ],
        )
        diag = json.loads((diagnosis / "diagnosis.json").read_text())
        _step(
            "3c",
            "identify the base model again on the campaign with the new runs (base and "
            "improved then see the same runs)",
            ["identify", str(campaign), "--model", args.model, "--out", str(base), "--force", *q],
        )
    found = [s["added"] for s in diag.get("ladder", []) if s.get("added")]
    add: list[str] = []
    for e in found:
        add += ["--add", e]
    _step(
        4,
        "identify again with the effects diagnosis named"
        if found
        else "identify again (diagnosis named no effect)",
        ["identify", str(campaign), "--model", args.model, *add, "--out", str(improved), *q],
    )
    report = out / "report.pdf"
    _step(
        5,
        "report: base and improved identification side by side, and the diagnosis",
        ["report", str(base), str(improved), str(diagnosis), "--out", str(report), *q],
    )

    fall = _error_fall(base, improved)
    print("\nSummary")
    print(f"  hidden effect in the simulated muscle : {args.hidden}")
    print(f"  effects diagnosis added (ladder)      : {', '.join(found) or 'none'}")
    print(f"  mean validation fit, base model       : {100 * (1 - fall.before):6.2f} %")
    print(f"  mean validation fit, with the effects : {100 * (1 - fall.after):6.2f} %")
    print(f"  {fall.sentence()}")
    print(f"  diagnosis: {_verdict(args.hidden, found, diag)}")
    print(f"  total {time.perf_counter() - t0:.0f} s")
    print(f"\nReport: {report.resolve()}")
    return 0
