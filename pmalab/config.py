"""Reading the user's text files (TOML rig/protocol/truth files, JSON results) with one-line errors.

Every reader of a user-edited file needs the same three steps: read the text (turning a
missing file, a directory, an unreadable or non-UTF-8 file into one line naming it), parse
it (naming the line and column of a syntax error), and refuse keys it does not know (a
misspelt key silently ignored is a wrong experiment).  They live here once; each area
keeps its own schema and wording of the unknown-key message.

Errors are :class:`~pmalab.errors.ConfigError` by default; pass ``error=`` for another
:class:`~pmalab.errors.PmalabError` subclass (the reports area uses its ``ReportError``).
"""

from __future__ import annotations

import json
import re
import tomllib
from collections.abc import Collection, Iterable, Mapping
from pathlib import Path
from typing import Any

from pmalab.errors import ConfigError, PmalabError

_TOML_AT = re.compile(r"\s*\(at (line \d+, column \d+|end of document)\)$")


def read_text(
    path: str | Path,
    what: str,
    *,
    where: str | None = None,
    hint: str = "",
    error: type[PmalabError] = ConfigError,
) -> str:
    """The UTF-8 text of ``path``; a one-line ``error`` naming it when it cannot be read.

    ``what`` names the kind of file in the message (``"rig file"``), ``where`` how the
    file is named (default: the path as given), ``hint`` is appended when it does not
    exist (e.g. what to use instead).
    """
    p = Path(path)
    where = str(path) if where is None else where
    try:
        return p.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise error(f"{where}: {what} not found{hint}") from None
    except IsADirectoryError:
        raise error(f"{where}: is a directory, not a {what}") from None
    except UnicodeDecodeError as exc:
        raise error(
            f"{where}: cannot read {what} (not UTF-8 text: byte {exc.start} is 0x{exc.object[exc.start]:02x})"
        ) from None
    except OSError as exc:
        raise error(f"{where}: cannot read {what} ({exc.strerror or exc})") from None


def parse_toml(text: str, where: str, *, error: type[PmalabError] = ConfigError) -> dict[str, Any]:
    """Parse TOML ``text``; a syntax error becomes one line naming ``where``, line and column."""
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        msg = str(exc)
        m = _TOML_AT.search(msg)
        at = f" at {m.group(1)}" if m else ""
        detail = msg[: m.start()] if m else msg
        raise error(f"{where}: not valid TOML{at} ({detail})") from None


def load_toml(
    path: str | Path,
    what: str,
    *,
    where: str | None = None,
    hint: str = "",
    error: type[PmalabError] = ConfigError,
) -> tuple[dict[str, Any], str]:
    """Read and parse a TOML file: ``(document, text)`` (the text is kept as provenance).

    Arguments as for :func:`read_text`.
    """
    where = str(path) if where is None else where
    text = read_text(path, what, where=where, hint=hint, error=error)
    return parse_toml(text, where, error=error), text


def load_json(
    path: str | Path,
    what: str,
    *,
    where: str | None = None,
    error: type[PmalabError] = ConfigError,
) -> Any:
    """Read and parse a JSON file; a syntax error names the file and the line."""
    where = str(path) if where is None else where
    text = read_text(path, what, where=where, error=error)
    try:
        return json.loads(text)
    except json.JSONDecodeError as exc:
        raise error(f"{where}: malformed JSON at line {exc.lineno} ({exc.msg})") from None


def unknown_keys(table: Mapping[str, Any], allowed: Collection[str]) -> list[str]:
    """The keys of ``table`` not in ``allowed``, in the file's order."""
    return [k for k in table if k not in allowed]


def check_keys(
    table: Mapping[str, Any],
    allowed: Collection[str],
    message: str,
    *,
    known: Iterable[str] | None = None,
    error: type[PmalabError] = ConfigError,
    **fields: Any,
) -> None:
    """Refuse the first key of ``table`` that is not in ``allowed``.

    ``message`` is a :meth:`str.format` template with ``{key}`` (the unknown key),
    ``{known}`` (``known``, default the sorted ``allowed``, joined by commas) and any
    ``fields`` given, e.g. ``"{where}: limits.{key}: unknown limit (known: {known})"``.
    """
    bad = unknown_keys(table, allowed)
    if bad:
        names = sorted(allowed) if known is None else list(known)
        raise error(message.format(key=bad[0], known=", ".join(names), **fields))
