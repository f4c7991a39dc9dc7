"""``pmalab report BASE_DIR [IMPROVED_DIR] [DIAG_DIR] --out REPORT.pdf``: the multi-page PDF
of one identification (and optionally an improved one, side by side) and a diagnosis."""

from __future__ import annotations

import argparse
import sys

from pmalab.console import VERBOSE, add_verbosity, show_progress, verbosity
from pmalab.lazy import gc_paused, is_the_command


def register(sub: argparse._SubParsersAction) -> None:
    """Add the ``report`` verb to the ``pmalab`` parser."""
    p = sub.add_parser(
        "report",
        help="multi-page PDF report of identification and/or diagnosis directories",
        description="Render result directories (identification.json, diagnosis.json, "
        "predictions.h5 as written by 'pmalab identify'/'pmalab diagnose') into one "
        "multi-page PDF.  Give one identification directory, or two (the base model first, "
        "then the model identified with --add) to draw them side by side, plus optionally a "
        "diagnosis directory; or the OUT directory of 'pmalab identify --model a,b,c' "
        "(laws.json): the laws ranked, their held-out loops law beside law on one error "
        "scale, then the best law's pages.  Pages for parts the directories lack are left "
        "out.",
    )
    p.add_argument(
        "directories",
        nargs="+",
        metavar="DIR",
        help="BASE_DIR [IMPROVED_DIR] [DIAG_DIR]: identification directories "
        "(base first) and/or a diagnosis directory, in any mix; or a laws directory "
        "(identify --model a,b,c); or 'pmalab control' run files (CONTROL.h5: a page per "
        "experiment); or antagonistic-pair run files (both muscles' loops, every run)",
    )
    p.add_argument("--out", required=True, metavar="REPORT.pdf", help="the PDF to write")
    p.add_argument("--force", action="store_true", help="overwrite existing outputs")
    exp = p.add_mutually_exclusive_group()
    exp.add_argument("--png", metavar="DIR", help="also export every page as PNG into DIR")
    exp.add_argument("--svg", metavar="DIR", help="also export every page as SVG into DIR")
    p.add_argument(
        "--jobs",
        type=_jobs,
        default=None,
        metavar="N",
        help="render the pages in N processes (default: $PMALAB_JOBS when set, else the "
        "number of CPUs; 1: in this process)",
    )
    add_verbosity(p, quiet_help="print nothing on success")
    p.set_defaults(func=run_report)


def _jobs(text: str) -> int:
    try:
        n = int(text)
    except ValueError:
        n = 0
    if n < 1:
        raise argparse.ArgumentTypeError(f"give a whole number >= 1, not {text!r}")
    return n


def run_report(args: argparse.Namespace) -> int:
    # matplotlib's and the report code's objects, frozen when this process imports them
    # first (a report run from the shell): the collector would walk them at every full
    # collection while the pages are drawn, about a tenth of a report's CPU (the pmalab
    # command only: a user's program calling it keeps its collector as it was)
    with gc_paused(freeze=is_the_command() and "matplotlib" not in sys.modules):
        from pmalab.reports.build import build_report

    level = verbosity(args)

    def line(text: str) -> None:
        print(text, flush=True)

    out = build_report(
        args.directories,
        args.out,
        args.force,
        png_dir=args.png,
        svg_dir=args.svg,
        progress=line if level >= VERBOSE else None,
        bar=show_progress(args),
        jobs=args.jobs,
    )
    if level > 0:
        print(f"report written: {out}", flush=True)
    return 0
