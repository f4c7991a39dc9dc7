"""``pmalab demo``: the whole chain on the simulated rig."""

from __future__ import annotations

import argparse


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("demo", help="simulated campaign -> identify -> diagnose -> PDF")
    p.add_argument("--out", default="demo-output", help="output directory")
    p.add_argument("--force", action="store_true", help="overwrite existing outputs")
    p.set_defaults(func=run_demo)


def run_demo(args: argparse.Namespace) -> int:
    raise NotImplementedError("demo is assembled once the chain exists")
