"""The ``pmalab`` command.

Each area registers its own verbs (``register(subparsers)`` in ``<area>/cli.py``), so this
module only dispatches and turns user errors into one line on stderr with a non-zero exit.
"""

from __future__ import annotations

import argparse
import importlib
import os
import sys
import textwrap
import warnings
from collections.abc import Callable
from pathlib import Path
from typing import Any

from pmalab import __version__
from pmalab.errors import PmalabError, RunFileWarning
from pmalab.lazy import the_command_starts
from pmalab.paths import missing_roots, remove_empty_dirs

#: modules that contribute verbs; each defines ``register(subparsers) -> None`` and sets
#: ``func(args) -> int`` as the parser default.
VERB_MODULES = (
    "pmalab.acquisition.cli",  # run, import, recover, check, view
    "pmalab.rig.cli",  # emulate
    "pmalab.identify.cli",  # identify, diagnose
    "pmalab.active.cli",  # diagnose --rig RIG --run-suggested (after identify.cli)
    "pmalab.reports.cli",  # report
    "pmalab.control.cli",  # control
    "pmalab.demo",  # demo
)


def _registered(module: str, registry: str, folder: str, key: str) -> list[str]:
    """The ids in ``module.registry`` when that module is loaded already (a user's law or
    effect registered at run time included), else the ids its source files declare
    (:func:`pmalab.registry.declared_ids`: help stays free of the numerical libraries)."""
    if module in sys.modules:
        return list(getattr(sys.modules[module], registry))
    from pmalab.registry import declared_ids

    return declared_ids(Path(__file__).parent.joinpath(*folder.split("/")), key)


def _laws() -> list[str]:
    return _registered("pmalab.identify.laws", "LAWS", "identify/laws", "name")


def _effects() -> list[str]:
    return _registered("pmalab.identify.effects", "EFFECTS", "identify/effects", "id")


def _controllers() -> list[str]:
    return _registered("pmalab.control.controllers", "CONTROLLERS", "control", "name")


def _rigs() -> list[str]:
    from pmalab.paths import RIGS_DIR, shipped_names

    return shipped_names(RIGS_DIR)


def _protocols() -> list[str]:
    from pmalab.paths import PROTOCOLS_DIR, shipped_names

    return shipped_names(PROTOCOLS_DIR)


#: placeholders a help text may hold, each filled from its registry (or the shipped files)
#: when help is printed, so the help names what exists; a parser builds without importing
#: the registries (``pmalab identify`` starts fast)
REGISTRY_PLACEHOLDERS: dict[str, Callable[[], list[str]]] = {
    "{laws}": _laws,
    "{effects}": _effects,
    "{controllers}": _controllers,
    "{protocols}": _protocols,
    "{rigs}": _rigs,
}


def fill_registries(text: str) -> str:
    """``text`` with each registry placeholder (``{laws}``, ...) replaced by the ids
    registered now, comma-separated; other braces are left alone."""
    for key, ids in REGISTRY_PLACEHOLDERS.items():
        if key in text:
            text = text.replace(key, ", ".join(ids()))
    return text


class RegistryHelpFormatter(argparse.HelpFormatter):
    """argparse's formatter, filling the registry placeholders of help texts and
    descriptions (:func:`fill_registries`) when help is printed."""

    def _expand_help(self, action: argparse.Action) -> str:
        return fill_registries(super()._expand_help(action))

    def _format_text(self, text: str) -> str:
        return super()._format_text(fill_registries(text))

    # ids such as prandtl-ishlinskii are wrapped whole, never split at their hyphens
    def _split_lines(self, text: str, width: int) -> list[str]:
        return textwrap.wrap(" ".join(text.split()), width, break_on_hyphens=False)

    def _fill_text(self, text: str, width: int, indent: str) -> str:
        return textwrap.fill(
            " ".join(text.split()),
            width,
            initial_indent=indent,
            subsequent_indent=indent,
            break_on_hyphens=False,
        )


class OneLineParser(argparse.ArgumentParser):
    """argparse's parser, but a mistake on the command line is one line (the quality bar:
    one line naming the option), with a pointer to ``--help`` instead of the usage block.
    Sub-command parsers inherit the class, and help texts name the registered laws,
    effects, ... (:class:`RegistryHelpFormatter`)."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        kwargs.setdefault("formatter_class", RegistryHelpFormatter)
        super().__init__(*args, **kwargs)

    def error(self, message: str):  # type: ignore[override]
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def build_parser() -> argparse.ArgumentParser:
    parser = OneLineParser(
        prog="pmalab",
        description="Pneumatic muscle workbench: run protocols, identify, diagnose, report.",
    )
    parser.add_argument("--version", action="version", version=f"pmalab {__version__}")
    sub = parser.add_subparsers(dest="verb", metavar="VERB")
    sub.required = True
    for name in VERB_MODULES:
        importlib.import_module(name).register(sub)
    return parser


#: argparse destinations that name outputs: a failed command removes the directories it
#: created for them when they are still empty ("a failed command leaves nothing behind")
OUTPUT_ARGS = ("out", "png", "svg", "plot")


def main(argv: list[str] | None = None) -> int:
    """Run one ``pmalab`` verb; the exit code.

    ``argv``: the command's arguments; None (the ``pmalab`` command): ``sys.argv``, and
    then BLAS is loaded on one thread for every verb and the first imports' objects are
    frozen (:func:`pmalab.lazy.the_command_starts`).  A user's own program calling
    ``main([...])`` keeps its environment, its BLAS thread count and its collector."""
    if argv is None:  # the pmalab command: this process is ours
        the_command_starts()
    parser = build_parser()
    try:
        args, extra = parser.parse_known_args(argv)
    except SystemExit as exc:  # --help, --version, or one line for a command-line mistake
        return exc.code if isinstance(exc.code, int) else 2
    if extra:  # argparse would blame `pmalab`; the option belongs to the verb's --help
        prog = f"{parser.prog} {args.verb}"
        print(
            f"{prog}: error: unrecognized arguments: {' '.join(extra)} (see {prog} --help)",
            file=sys.stderr,
        )
        return 2
    outputs = [v for k in OUTPUT_ARGS if isinstance(v := getattr(args, k, None), str) and v]
    created = missing_roots(outputs)
    rc = 1
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("always", RunFileWarning)
            warnings.showwarning = _one_line_warning(args.verb)
            rc = _dispatch(args)
        return rc
    finally:
        if rc != 0:
            remove_empty_dirs(created)


def _one_line_warning(verb: str):
    """``warnings.showwarning`` for the CLI: pmalab's warnings as one line on stderr."""
    default = warnings.showwarning

    def show(message, category, filename, lineno, file=None, line=None):
        if issubclass(category, RunFileWarning):
            print(f"pmalab {verb}: warning: {message}", file=sys.stderr)
        else:
            default(message, category, filename, lineno, file, line)

    return show


def _dispatch(args: argparse.Namespace) -> int:
    try:
        return int(args.func(args) or 0)
    except PmalabError as exc:
        print(f"pmalab {args.verb}: error: {exc}", file=sys.stderr)
        if exc.hard_exit:  # HDF5 holds a file it could not close: skip its crash at exit
            sys.stdout.flush()
            sys.stderr.flush()
            os._exit(exc.exit_code)
        return exc.exit_code
    except KeyboardInterrupt:
        print(f"pmalab {args.verb}: interrupted", file=sys.stderr)
        return 130
    except OSError as exc:
        # the file system refused (no permission, disk full, a file where a directory
        # should be): the user's to fix, so one line too; verbs name their files where
        # they can, this is the net for the places that do not
        print(f"pmalab {args.verb}: error: {os_error_line(exc)}", file=sys.stderr)
        return PmalabError.exit_code


def os_error_line(exc: OSError) -> str:
    """``FILE: reason`` for an ``OSError`` (``errno`` text, else its first line)."""
    if exc.errno:
        reason = os.strerror(exc.errno)
    else:
        reason = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
    names = [str(n) for n in (exc.filename, exc.filename2) if n is not None]
    return f"{' → '.join(names)}: {reason}" if names else reason


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
