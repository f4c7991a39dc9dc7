"""``pmalab report DIR --out REPORT.pdf``: the multi-page PDF of a result directory."""

from __future__ import annotations

import argparse


def register(sub: argparse._SubParsersAction) -> None:
    """Add the ``report`` verb to the ``pmalab`` parser."""
    p = sub.add_parser(
        "report",
        help="multi-page PDF report of an identification and/or diagnosis directory",
        description="Render DIR (identification.json, diagnosis.json, predictions.h5 as "
        "written by 'pmalab identify'/'pmalab diagnose') into a multi-page PDF.  Pages for "
        "parts a directory lacks are left out.",
    )
    p.add_argument("directories", nargs="+", metavar="DIR",
                   help="identification and/or diagnosis output directory (several are merged "
                   "into one report, e.g. an identify --out and a diagnose --out), or "
                   "'pmalab control' run files (CONTROL.h5: a page per experiment)")
    p.add_argument("--out", required=True, metavar="REPORT.pdf", help="the PDF to write")
    p.add_argument("--force", action="store_true", help="overwrite existing outputs")
    exp = p.add_mutually_exclusive_group()
    exp.add_argument("--png", metavar="DIR", help="also export every page as PNG into DIR")
    exp.add_argument("--svg", metavar="DIR", help="also export every page as SVG into DIR")
    p.add_argument("--quiet", action="store_true", help="no progress lines")
    p.set_defaults(func=run_report)


def run_report(args: argparse.Namespace) -> int:
    from pmalab.reports.build import build_report

    out = build_report(args.directories, args.out, args.force, png_dir=args.png,
                       svg_dir=args.svg, progress=None if args.quiet else print)
    if not args.quiet:
        print(f"report written: {out}")
    return 0
