"""Where shipped data lives (protocols, rig files, truth files, the controllers'
identifications, the real measurements), and the checks every output path goes through.

The shipped data is package data (``pmalab/data``), found through
:mod:`importlib.resources`, so an installed wheel has it; a clone also has ``data/`` at its
top (a link to the same folder), so ``data/rigs/labjack-t7.toml`` typed there works, and
:func:`shipped` lets the same text work anywhere else.
"""

from __future__ import annotations

import os
import re
from collections.abc import Callable, Iterable
from importlib.resources import files
from pathlib import Path

from pmalab.errors import OutputError, OutputExistsError

#: the shipped data (a real folder: wheels install unzipped)
DATA_DIR = Path(str(files("pmalab") / "data"))
PROTOCOLS_DIR = DATA_DIR / "protocols"
RIGS_DIR = DATA_DIR / "rigs"
TRUTH_DIR = DATA_DIR / "truth"


def shipped(spec: str | Path, folder: Path, suffix: str = ".toml") -> Path:
    """``spec`` as given when it exists; else the shipped file it names.

    Accepted names: the name inside ``folder`` (``seed-bouc-wen``, ``subtle/clean``), with
    or without its suffix, or the path a clone shows (``data/rigs/labjack-t7.toml``), so
    commands copied from the docs work outside the repository too.  Returns ``spec`` unchanged when nothing matches (the caller's
    reader then says "no such file" for the path the user typed).
    """
    p = Path(spec)
    if p.exists():
        return p
    parts = p.parts
    if len(parts) > 1 and parts[0] == "data":
        cand = DATA_DIR.joinpath(*parts[1:])
        if cand.exists():
            return cand
    if not p.is_absolute() and ".." not in parts:
        for cand in (folder / p, folder / f"{p}{suffix}"):
            if cand.is_file():
                return cand
    return p


def shipped_names(folder: Path, suffix: str = ".toml") -> list[str]:
    """The names a user can give for the files shipped in ``folder`` (``seed-bouc-wen``,
    ``subtle/clean``: the path inside ``folder`` without ``suffix``), sorted."""
    if not folder.is_dir():
        return []
    return sorted(
        p.relative_to(folder).with_suffix("").as_posix() for p in folder.rglob(f"*{suffix}")
    )


def shipped_hint(folder: Path, what: str, suffix: str = ".toml") -> str:
    """`` (shipped WHAT: a, b, c)`` for an error about a name that matched nothing."""
    names = shipped_names(folder, suffix)
    return f" (shipped {what}: {', '.join(names)})" if names else ""


def check_output(path: str | Path, force: bool) -> Path:
    """Refuse to overwrite ``path`` unless ``force``; return it as a Path.

    Also refuses, before any work is done, an output file that could never be written: a
    directory of that name (even with ``force``), or a path below an existing file.
    """
    p = Path(path)
    if p.is_dir():
        raise OutputError(f"{p}: is a directory (give a file name)")
    if p.exists() and not force:
        raise OutputExistsError(f"{p}: already exists (use --force to overwrite)")
    parent = next((a for a in p.parents if a.exists()), None)
    if parent is not None and not parent.is_dir():
        raise OutputError(f"{p}: cannot write ({parent} is a file, not a directory)")
    return p


def output_failure(path: str | Path, exc: Exception, what: str = "write") -> OutputError:
    """A one-line :class:`OutputError` for an ``OSError`` while writing ``path`` (or the
    ``RuntimeError`` HDF5 raises when it cannot flush, e.g. on a full disk)."""
    code = getattr(exc, "errno", None)
    text = str(exc)
    m = re.search(r"error message = '([^']*)'", text)  # HDF5: the OS's reason inside
    if code:
        reason = os.strerror(code)
    elif m:
        reason = m.group(1)
    else:
        reason = text.strip().splitlines()[0] if text.strip() else type(exc).__name__
    return OutputError(f"{path}: cannot {what} ({reason})")


def prepare_output_dir(directory: str | Path, names: tuple[str, ...], force: bool) -> Path:
    """Check, before any work, that ``directory/<name>`` can all be written.

    Refuses existing outputs without ``force`` and unwritable places with one line.  The
    directory is not created here (the writer creates it when the results exist), so a
    command that fails later leaves no empty directory behind.
    """
    d = Path(directory)
    if d.exists() and not d.is_dir():
        raise OutputError(f"{d}: exists and is not a directory")
    for n in names:
        check_output(d / n, force)
    base = d if d.exists() else next((a for a in d.parents if a.exists()), Path("."))
    if not os.access(base, os.W_OK | os.X_OK):
        what = "this directory" if base == d else f"{base}"
        raise OutputError(f"{d}: cannot write into {what} (permission denied)")
    return d


def missing_roots(paths: Iterable[str | Path]) -> list[Path]:
    """For each output path, the outermost of it and its parents that does not exist yet
    (what a command may create); paths that exist give nothing."""
    roots: list[Path] = []
    for p in paths:
        p = Path(p)
        if p.exists():
            continue
        root = p
        for a in p.parents:
            if a.exists():
                break
            root = a
        roots.append(root)
    return roots


def remove_empty_dirs(roots: list[Path]) -> None:
    """Remove the directories a failed command created and left empty (never a file)."""
    for root in roots:
        if not root.is_dir() or root.is_symlink():
            continue
        for dirpath, _dirs, _files in sorted(os.walk(root), key=lambda w: -len(w[0])):
            try:
                os.rmdir(dirpath)  # only succeeds when empty
            except OSError:
                pass


def write_together(writers: dict[Path, Callable[[Path], object]]) -> None:
    """Write several outputs as one: each writer fills a temporary ``NAME.tmp`` next to its
    path, and only when all succeeded is each renamed into place — a failure (a full disk)
    leaves none of them behind."""
    tmps = {p: p.with_name(p.name + ".tmp") for p in writers}
    try:
        for p, write in writers.items():
            write(tmps[p])
    except BaseException:
        for t in tmps.values():
            t.unlink(missing_ok=True)
        raise
    for p, t in tmps.items():
        t.replace(p)
