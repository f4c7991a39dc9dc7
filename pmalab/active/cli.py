"""``pmalab diagnose ... --rig RIG --run-suggested``: the diagnosis runs the experiment it
suggests (see :mod:`pmalab.active.loop`).

``diagnose`` itself is registered by :mod:`pmalab.identify.cli`; identification never
touches the rig, so the options that do are added here, one layer up, and the verb's
function is wrapped: without ``--run-suggested`` nothing changes.
"""

from __future__ import annotations

import argparse
import signal
import sys
from pathlib import Path

from pmalab.arguments import check_max_steps, law_names
from pmalab.arguments import seed as seed_arg
from pmalab.errors import PmalabError


def register(sub: argparse._SubParsersAction) -> None:
    """Add the rig options to the ``diagnose`` verb registered by ``pmalab.identify.cli``."""
    p = sub.choices["diagnose"]
    g = p.add_argument_group(
        "active identification (run the suggested experiment on a rig)",
        "With --run-suggested and --rig, an ambiguous verdict makes pmalab design the "
        "experiment that separates the candidate effects most relative to the noise floor, "
        "show it as a protocol with the reason, ask before the rig moves (--yes: don't ask), "
        "record it through the same safety runner as 'pmalab run', append the runs to the "
        "campaign (one FILE.h5) and diagnose again, until the verdict is clear, nothing is "
        "worth measuring, or the budget is spent.",
    )
    g.add_argument("--rig", metavar="RIG", help="'sim' or a rig TOML file to record on")
    g.add_argument(
        "--run-suggested",
        action="store_true",
        help="run the suggested experiments on --rig and re-diagnose",
    )
    g.add_argument(
        "--budget",
        type=float,
        default=300.0,
        metavar="S",
        help="rig time the loop may use, in seconds (default 300)",
    )
    g.add_argument(
        "--rounds", type=int, default=3, metavar="N", help="most experiments to run (default 3)"
    )
    g.add_argument(
        "--yes",
        action="store_true",
        help="run suggested experiments without asking (scripts, simulated rig)",
    )
    g.add_argument(
        "--seed",
        type=seed_arg,
        default=None,
        help="simulated rig: sensor-noise seed of the first round (+1 per round)",
    )
    plain = p.get_default("func")
    p.set_defaults(
        func=lambda args: run_active(args) if args.run_suggested or args.rig else plain(args)
    )


def run_active(args: argparse.Namespace) -> int:
    from pmalab.active.loop import (
        RoundAborted,
        diagnose_active,
        protocol_duration,
        rig_recorder,
    )
    from pmalab.identify.cli import resolve_jobs
    from pmalab.identify.diagnosis import write_outputs
    from pmalab.paths import prepare_output_dir

    if not args.run_suggested:
        raise PmalabError(
            "--rig: only used with --run-suggested (run the suggested experiments on this rig)"
        )
    if not args.rig:
        raise PmalabError("--run-suggested: needs --rig (sim or a rig TOML file)")
    if len(args.files) != 1:
        raise PmalabError(
            "--run-suggested: give exactly one campaign file (the new runs are "
            f"appended to it), got {len(args.files)}"
        )
    if args.validate:
        raise PmalabError(
            "--run-suggested: tag held-out runs with role 'validation' in the "
            "campaign instead of --validate (new runs are appended to it)"
        )
    # the options a plain diagnosis takes that the loop cannot honour: refused, never ignored
    unsupported = [
        flag
        for flag, on in (
            ("--scheduler", getattr(args, "scheduler", None)),
            ("--static", getattr(args, "static", False)),
            ("--muscle", getattr(args, "muscle", None)),
            ("--include-aborted", getattr(args, "include_aborted", False)),
            ("--plot", getattr(args, "plot", None)),
            ("--pressure measured", getattr(args, "pressure", "nominal") == "measured"),
        )
        if on
    ]
    if unsupported:
        raise PmalabError(
            f"--run-suggested: {', '.join(unsupported)} cannot be used with it (the loop "
            "diagnoses the whole campaign file locally after every round)"
        )
    check_max_steps(args.max_steps)
    jobs = resolve_jobs(args.jobs)  # --jobs, else $PMALAB_JOBS, else 2
    if args.budget <= 0:
        raise PmalabError(f"--budget {args.budget:g}: must be a positive number of seconds")
    if args.rounds < 1:
        raise PmalabError(f"--rounds {args.rounds}: must be at least 1")
    campaign = Path(args.files[0])
    if not campaign.is_file():
        raise PmalabError(f"{campaign}: no such campaign file")
    out = prepare_output_dir(args.out, ("diagnosis.json", "predictions.h5"), args.force)
    record = rig_recorder(
        args.rig, seed=args.seed, quiet=args.quiet if hasattr(args, "quiet") else True
    )

    def confirm(exp, toml: str) -> bool:
        print(f"\nSuggested experiment ({exp.duration_s:.0f} s of rig time on {args.rig}):")
        print(toml)
        if args.yes:
            return True
        if not sys.stdin.isatty():
            raise PmalabError(
                "the suggested experiment needs confirmation: run interactively or add --yes"
            )
        ans = input(f"Run it on {args.rig}? [y/N] ").strip().lower()
        return ans in ("y", "yes")

    def on_term(signum, frame):  # SIGTERM ends the round like Ctrl-C: vent, keep, exit
        raise KeyboardInterrupt

    old = signal.signal(signal.SIGTERM, on_term)
    try:
        res = diagnose_active(
            campaign,
            record,
            model=args.model,
            budget_s=args.budget,
            confirm=confirm,
            max_rounds=args.rounds,
            effects=args.only,
            jobs=jobs,
            protocol_duration=protocol_duration,
            # the plain diagnosis's own settings, for the first diagnosis and every round's
            options={
                "laws": law_names(args.laws),
                "max_steps": args.max_steps,
                "effects_files": args.effects,
                "whole_run": args.whole_run,
            },
        )
    except RoundAborted as exc:
        _write(exc.partial, out, args.force, write_outputs)
        exc.args = (
            f"{exc}; {campaign} is unchanged, the round's samples are in "
            f"{exc.round_file}; diagnosis of the campaign so far in {out}",
        )
        raise exc from None
    finally:
        signal.signal(signal.SIGTERM, old)
    d = res.diagnosis
    print(
        f"\nEffect ranking after {len(res.rounds)} round(s) "
        f"(noise floor {d.noise_floor['mean_nrmse']:.4f}):"
    )
    print(d.ranking_table())
    for r in res.rounds:
        v = r.verdict
        print(
            f"round {r.round}: {r.experiment['label']} ({r.rig_time_s:.0f} s), expected "
            f"separation {r.expected_separation['min_x_floor']:.1f}× floor → first "
            f"{v['first']}"
            + (f", ambiguous {', '.join(v['ambiguous'])}" if v["ambiguous"] else ", not ambiguous")
        )
    print(f"\n{d.summary}")
    print(
        f"Stopped: {res.stop_text} ({res.rig_time_s:.0f} s of {res.budget_s:.0f} s rig time used)."
    )
    jpath, hpath = _write(res, out, args.force, write_outputs)
    print(f"wrote {jpath} and {hpath}")
    return 0


def _write(res, out: Path, force: bool, write_outputs) -> tuple[Path, Path]:
    """diagnosis.json (with the active rounds) and predictions.h5, written together."""
    return write_outputs(res.final(), out, force=force)
