"""The ``pmalab`` command.

Each area registers its own verbs (``register(subparsers)`` in ``<area>/cli.py``), so this
module only dispatches and turns user errors into one line on stderr with a non-zero exit.
"""

from __future__ import annotations

import argparse
import importlib
import sys

from pmalab import __version__
from pmalab.errors import PmalabError

#: modules that contribute verbs; each defines ``register(subparsers) -> None`` and sets
#: ``func(args) -> int`` as the parser default.
VERB_MODULES = (
    "pmalab.acquisition.cli",  # run, import, recover
    "pmalab.rig.cli",  # emulate
    "pmalab.identify.cli",  # identify, diagnose
    "pmalab.reports.cli",  # report
    "pmalab.demo",  # demo
)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="pmalab",
        description="Pneumatic muscle workbench: run protocols, identify, diagnose, report.",
    )
    parser.add_argument("--version", action="version", version=f"pmalab {__version__}")
    sub = parser.add_subparsers(dest="verb", metavar="VERB")
    sub.required = True
    for name in VERB_MODULES:
        importlib.import_module(name).register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except PmalabError as exc:
        print(f"pmalab {args.verb}: error: {exc}", file=sys.stderr)
        return exc.exit_code
    except KeyboardInterrupt:
        print(f"pmalab {args.verb}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
