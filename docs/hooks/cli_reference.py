"""MkDocs hook: the CLI reference page is generated from pmalab's own argparse parsers.

A page holding the line ``<!-- pmalab-cli-reference -->`` gets one section per verb: its
description, usage and every option with its help, exactly as ``pmalab VERB --help``
prints them (so the reference can never drift from the code).
"""

from __future__ import annotations

import argparse
import os

MARKER = "<!-- pmalab-cli-reference -->"


def _verbs() -> list[tuple[str, argparse.ArgumentParser]]:
    from pmalab.cli import build_parser

    parser = build_parser()
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return sorted(sub.choices.items())


def render() -> str:
    from pmalab.cli import fill_registries

    os.environ.setdefault("COLUMNS", "100")  # argparse wraps help at the terminal width
    out = ["Generated from the parsers at build time: what `pmalab VERB --help` prints.\n"]
    for name, p in _verbs():
        out.append(f"## `pmalab {name}`\n")
        if p.description:
            out.append(fill_registries(p.description.strip()) + "\n")
        help_text = p.format_help()
        out.append("```text\n" + help_text.rstrip() + "\n```\n")
    return "\n".join(out)


def on_page_markdown(markdown: str, page, config, files) -> str:
    if MARKER in markdown:
        return markdown.replace(MARKER, render())
    return markdown
