"""CLI verbs of this area (see pmalab/cli.py)."""

from __future__ import annotations

import argparse


def register(sub: argparse._SubParsersAction) -> None:
    """Add this area's verbs to the ``pmalab`` parser (filled in by the area's issue)."""
