"""MkDocs hook: the pages show what the user will see, made by the build.

* **Tutorial output.**  A page listed in :data:`RUN_PAGES` has its ``bash`` blocks run, in
  order, in an empty directory (as a user would type them); each block is followed on the
  page by what it printed (a ``text`` block), and a line ``<!-- pmalab-figures: GLOB -->``
  becomes the PNG figures the commands wrote that match ``GLOB`` (relative to the
  directory the commands ran in).
* **The notebook.**  ``<!-- pmalab-notebook: PATH -->`` becomes the notebook executed at
  build (nbclient): its markdown, its code and every output, figures inline.
* **Figures.**  ``docs/make_figures.py``'s figures (``generated/figures/loop.png``) and the
  report pages of the campaign tutorial (the gallery page: ``<!-- pmalab-gallery -->``).

Each of these *units* (one per run page, one per notebook, the figure script) is made in
its own cache directory, ``$XDG_CACHE_HOME/pmalab/docs/<unit>/<key>``, keyed by the hash of
pmalab's code (docstrings and comments excluded: editing them reruns nothing) and the
unit's own inputs (a page's commands, not its prose).  The outputs are added to the site as
generated files: the build writes nothing into the tree (``make docs`` leaves it clean), a
second build with unchanged code costs nothing, and a change of the code or of a page's
commands makes that unit again.  Missing units are made two at a time; a unit is made by
one process at a time (a lock file beside it): a test that reads what a page's commands made
(:func:`unit`) waits for a build making it, never makes it a second time.
"""

from __future__ import annotations

import ast
import base64
import contextlib
import hashlib
import json
import os
import re
import shutil
import subprocess
import sys
import tempfile
from collections.abc import Iterator
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

from mkdocs.structure.files import File, Files

DOCS = Path(__file__).resolve().parents[1]
#: pages whose commands the build runs and shows with their output (the rest show their
#: commands only); a page's commands run in ``generated/runs/<page stem>``
RUN_PAGES = (
    "tutorials/campaign.md",
    "tutorials/import.md",
    "tutorials/static-characterization.md",
    "tutorials/control.md",
    "tutorials/bouc-wen-benchmark.md",
    "how-to/rig-file.md",
)
#: the tutorial whose report pages make the gallery, and where its commands write them
GALLERY = ("tutorials/campaign.md", "report-pages")
#: ``<!-- pmalab-figures: GLOB -->``: the PNGs the page's commands wrote matching GLOB
FIG = re.compile(r"^<!-- pmalab-figures: (\S+) -->$", re.M)
NOTEBOOK = re.compile(r"^<!-- pmalab-notebook: (\S+) -->$", re.M)
BASH = re.compile(r"```bash\n(.*?)```\n", re.S)
OUTPUT_LINES = 60  # a block's output is cut to this many lines (with a note)
FIGURE_SCRIPT = "make_figures"

#: part of every cache key: raise it when what a unit makes changes
CACHE_VERSION = "2"
KEEP = 3  # builds kept per unit (older code's outputs are removed)

_state: dict[str, str] = {}
_dirs: dict[str, Path] = {}  # the units made for this process's build


# --------------------------------------------------------------------------- the cache
def code_hash() -> str:
    """The hash of pmalab's code as it runs: each module's syntax tree without its
    docstrings (comments are not in it), and the package's data files byte for byte.

    Parsing every module takes most of a CPU-second, and each process that asks (every
    build, a test reading a unit) would pay it: the hash is kept in the cache under the
    files' identity as the file system states it (path, size, inode, modification and
    change times: a change of content changes the change time, which no tool sets back),
    so a process whose files are those of an earlier one reads it instead."""
    if "code" in _state:
        return _state["code"]
    import pmalab

    src = Path(pmalab.__file__).parent
    files = [p for p in sorted(src.rglob("*")) if "__pycache__" not in p.parts and p.is_file()]
    stamp = hashlib.sha256(str(src).encode())
    for p in files:
        st = p.stat()
        stamp.update(f"{p.relative_to(src)}\0{st.st_size} {st.st_ino} {st.st_mtime_ns} "
                     f"{st.st_ctime_ns}\0".encode())
    kept = _cache_root() / "code-hash" / stamp.hexdigest()[:32]
    with contextlib.suppress(OSError):
        _state["code"] = kept.read_text().strip()
        if re.fullmatch(r"[0-9a-f]{16}", _state["code"]):
            return _state["code"]
    h = hashlib.sha256()
    for p in files:
        if p.suffix == ".py":
            h.update(str(p.relative_to(src)).encode())
            h.update(_without_docstrings(p.read_text(encoding="utf-8")).encode())
        else:  # data: rig and protocol files, measurements, the live page
            h.update(str(p.relative_to(src)).encode())
            h.update(p.read_bytes())
    _state["code"] = h.hexdigest()[:16]
    with contextlib.suppress(OSError):  # a cache that cannot be written: computed again
        kept.parent.mkdir(parents=True, exist_ok=True)
        tmp = kept.with_name(f"{kept.name}.{os.getpid()}")
        tmp.write_text(_state["code"] + "\n")
        os.replace(tmp, kept)
        _prune_stamps(kept.parent, keep=20)
    return _state["code"]


def _prune_stamps(root: Path, keep: int) -> None:
    """Keep the ``keep`` newest code-hash entries (one per state of the files seen)."""
    entries = sorted(root.iterdir(), key=lambda p: p.stat().st_mtime, reverse=True)
    for old in entries[keep:]:
        old.unlink(missing_ok=True)


def _without_docstrings(text: str) -> str:
    tree = ast.parse(text)
    for node in ast.walk(tree):
        if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)):
            body = node.body
            if body and isinstance(body[0], ast.Expr) and isinstance(body[0].value, ast.Constant):
                if isinstance(body[0].value.value, str):
                    del body[0]  # a docstring added, edited or removed is the same code
                    body[:] = body or [ast.Pass()]
    return ast.dump(tree)


def _units() -> dict[str, tuple[str, bytes]]:
    """unit name → (kind, the bytes of its own inputs)."""
    units: dict[str, tuple[str, bytes]] = {}
    for page in RUN_PAGES:  # the commands, not the prose around them
        cmds = "\n".join(BASH.findall((DOCS / page).read_text(encoding="utf-8")))
        units[Path(page).stem] = ("page:" + page, cmds.encode())
    for nb in _notebooks():
        units["notebook-" + nb.stem] = ("notebook:" + str(nb), nb.read_bytes())
    units[FIGURE_SCRIPT] = ("script", (DOCS / "make_figures.py").read_bytes())
    return units


def _notebooks() -> list[Path]:
    out = []
    for page in DOCS.rglob("*.md"):
        for m in NOTEBOOK.finditer(page.read_text(encoding="utf-8")):
            out.append((page.parent / m.group(1)).resolve())
    return sorted(set(out))


def _cache_root() -> Path:
    base = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache")
    return base / "pmalab" / "docs"


def _env() -> dict[str, str]:
    env = dict(os.environ)
    env["PATH"] = str(Path(sys.executable).parent) + os.pathsep + env.get("PATH", "")
    env["MPLBACKEND"] = "Agg"
    env["COLUMNS"] = "100"
    return env


def _run_page(page: str, out: Path) -> None:
    """Run the page's bash blocks in order in ``generated/runs/<stem>``; their outputs go
    to ``outputs.json`` (one text per block)."""
    work = out / "generated" / "runs" / Path(page).stem
    work.mkdir(parents=True)
    texts = []
    for block in BASH.findall((DOCS / page).read_text(encoding="utf-8")):
        p = subprocess.run(
            ["bash", "-c", "set -euo pipefail\n" + block],
            cwd=work,
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,  # interleaved as a terminal shows them
            stdin=subprocess.DEVNULL,
            text=True,
            env=_env(),
            timeout=1800,
        )
        if p.returncode != 0:
            raise RuntimeError(f"{page}: a command failed:\n{block}\n{p.stdout[-3000:]}")
        texts.append(p.stdout)
    (out / "outputs.json").write_text(json.dumps(texts, indent=1))


def _make(kind: str, out: Path) -> None:
    if kind.startswith("page:"):
        _run_page(kind[5:], out)
    elif kind.startswith("notebook:"):
        nb = Path(kind[9:])
        md = _notebook_markdown(nb, out / "generated" / "figures" / "notebooks", nb.stem)
        (out / "notebook.md").write_text(md)
    else:
        subprocess.run(
            [sys.executable, str(DOCS / "make_figures.py"), str(out / "generated" / "figures")],
            check=True,
            capture_output=True,
            env=_env(),
            timeout=1800,
        )


def _notebook_markdown(path: Path, fig_dir: Path, stem: str) -> str:
    """The notebook executed, as markdown: cells, text outputs, figures as PNG files."""
    import nbclient
    import nbformat

    nb = nbformat.read(path, as_version=4)
    with tempfile.TemporaryDirectory() as run_dir:
        nbclient.NotebookClient(
            nb, timeout=1800, kernel_name="python3", resources={"metadata": {"path": run_dir}}
        ).execute()
    fig_dir.mkdir(parents=True, exist_ok=True)
    parts: list[str] = []
    n_fig = 0
    for cell in nb.cells:
        if cell.cell_type == "markdown":  # its headings one level under the page's title
            parts.append(re.sub(r"^(#+) ", r"#\1 ", cell.source, flags=re.M))
            continue
        if cell.cell_type != "code":
            continue
        parts.append(f"```python\n{cell.source}\n```")
        for o in cell.get("outputs", []):
            data = o.get("data", {})
            if "image/png" in data:
                n_fig += 1
                name = f"{stem}-{n_fig}.png"
                (fig_dir / name).write_bytes(base64.b64decode(data["image/png"]))
                parts.append(f"![figure {n_fig} of the notebook](FIGURES/notebooks/{name})")
            text = o.get("text") or data.get("text/plain") or ""
            if isinstance(text, list):
                text = "".join(text)
            if text.strip() and "image/png" not in data:
                parts.append(f"```text\n{_cut(text)}\n```")
    return "\n\n".join(parts) + "\n"


def _cut(text: str) -> str:
    lines = text.rstrip().splitlines()
    if len(lines) <= OUTPUT_LINES:
        return "\n".join(lines)
    return "\n".join([*lines[:OUTPUT_LINES], f"… ({len(lines) - OUTPUT_LINES} more lines)"])


def _unit_dir(name: str, inputs: bytes) -> Path:
    h = hashlib.sha256()
    for part in (CACHE_VERSION, code_hash(), name):
        h.update(part.encode() + b"\0")
    h.update(inputs)
    return _cache_root() / name / h.hexdigest()[:16]


@contextlib.contextmanager
def _making(final: Path) -> Iterator[None]:
    """Hold the unit's lock (``<key>.lock`` beside its directory) while it is made: another
    process that wants the same unit (a second build, a test reading its outputs) waits,
    then finds it made.  Without ``fcntl`` (not POSIX) nothing is locked and two makers
    may both make it; the first to finish is kept."""
    try:
        import fcntl
    except ImportError:  # pragma: no cover - not POSIX
        yield
        return
    with open(final.parent / f"{final.name}.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)  # released when the file is closed
        yield


@contextlib.contextmanager
def _reading(final: Path) -> Iterator[None]:
    """Hold the unit's lock shared while its files are read: :func:`_prune` (another
    checkout's build, with other code) leaves a unit being read alone."""
    try:
        import fcntl
    except ImportError:  # pragma: no cover - not POSIX
        yield
        return
    with open(final.parent / f"{final.name}.lock", "a") as lock:
        fcntl.flock(lock, fcntl.LOCK_SH)
        yield


def _make_unit(final: Path, kind: str) -> None:
    final.parent.mkdir(parents=True, exist_ok=True)
    with _making(final):
        if not (final / "done").exists():  # else made while this process waited
            _make_locked(final, kind)


def _make_locked(final: Path, kind: str) -> None:
    tmp = Path(tempfile.mkdtemp(prefix="making-", dir=final.parent))
    try:
        _make(kind, tmp)
        (tmp / "done").write_text("")
        if (final / "done").exists():  # another build made it meanwhile and may be using it
            shutil.rmtree(tmp, ignore_errors=True)
        else:
            if final.exists():  # a leftover without "done"
                shutil.rmtree(final, ignore_errors=True)
            os.replace(tmp, final)
    except OSError:
        shutil.rmtree(tmp, ignore_errors=True)
        if not (final / "done").exists():  # not a race lost to another build
            raise
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    _prune(final.parent, KEEP)


def unit(name: str) -> Path:
    """One unit's cache directory for the current code and inputs (``name``: a run page's
    stem, ``notebook-<stem>`` or ``make_figures``), made when missing, alone.  The tests
    that check what a tutorial's commands did read it there instead of running the same
    commands again."""
    kind, inputs = _units()[name]
    final = _unit_dir(name, inputs)
    if not (final / "done").exists():
        _make_unit(final, kind)
    return final


def unit_copy(name: str, dest: Path) -> Path:
    """:func:`unit` copied to ``dest`` (a new directory), read under the unit's lock: the
    cache keeps only the newest builds of a unit, and a build of other code (another
    checkout) may remove this one while a test still reads it; the copy stays."""
    while True:
        final = unit(name)
        with _reading(final):
            if (final / "done").exists():  # else removed before the lock: make it again
                shutil.copytree(final, dest)
                return dest


def built() -> dict[str, Path]:
    """Every unit's cache directory for the current code and inputs, made when missing
    (two at a time; the notebook in this thread, as its kernel client wants)."""
    if _dirs:
        return dict(_dirs)
    units = _units()
    dirs = {name: _unit_dir(name, inputs) for name, (_, inputs) in units.items()}
    todo = [n for n, d in dirs.items() if not (d / "done").exists()]
    threaded = [n for n in todo if not units[n][0].startswith("notebook:")]
    with ThreadPoolExecutor(max_workers=max(1, min(2, os.cpu_count() or 1))) as pool:
        futures = [pool.submit(_make_unit, dirs[n], units[n][0]) for n in threaded]
        for n in todo:
            if n not in threaded:
                _make_unit(dirs[n], units[n][0])
        for f in futures:
            f.result()
    _dirs.update(dirs)
    return dict(dirs)


def _prune(root: Path, keep: int) -> None:
    """Remove all but the ``keep`` most recently made builds of a unit."""
    done = sorted(
        (d for d in root.iterdir() if (d / "done").exists()),
        key=lambda d: (d / "done").stat().st_mtime,
        reverse=True,
    )
    try:
        import fcntl
    except ImportError:  # pragma: no cover - not POSIX
        fcntl = None
    for old in done[keep:]:
        lock_path = root / f"{old.name}.lock"
        with open(lock_path, "a") as lock:
            if fcntl is not None:
                try:  # a unit being read (:func:`_reading`) or made is left for later
                    fcntl.flock(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
                except OSError:
                    continue
            shutil.rmtree(old, ignore_errors=True)
            lock_path.unlink(missing_ok=True)


# --------------------------------------------------------------------------- the hooks
def on_config(config):
    """Each build (``mkdocs serve`` rebuilds too) looks at the code and the pages afresh."""
    _state.clear()
    _dirs.clear()
    return config


def on_files(files: Files, config) -> Files:
    for root in built().values():
        for png in sorted((root / "generated").rglob("*.png")):
            files.append(
                File(
                    png.relative_to(root).as_posix(),  # generated/...
                    src_dir=str(root),
                    dest_dir=config["site_dir"],
                    use_directory_urls=config["use_directory_urls"],
                )
            )
    return files


def _up(page_src: str) -> str:
    """The relative path from a page to the site root (``../`` per folder)."""
    return "../" * page_src.count("/")


def on_page_markdown(markdown: str, page, config, files) -> str:
    src = page.file.src_uri
    units = built()
    up = _up(src)
    if src in RUN_PAGES:
        root = units[Path(src).stem]
        it = iter(json.loads((root / "outputs.json").read_text()))

        def with_output(m: re.Match[str]) -> str:
            text = next(it, "").rstrip().lstrip("\n")  # keep the first line's indent
            shown = f"\n```text\n{_cut(text)}\n```\n" if text else ""
            return m.group(0) + shown

        markdown = BASH.sub(with_output, markdown)
        work = root / "generated" / "runs" / Path(src).stem

        def figures(m: re.Match[str]) -> str:
            pngs = sorted(work.glob(m.group(1)))
            if not pngs:
                raise RuntimeError(f"{src}: no figure matches {m.group(1)}")
            return "\n\n".join(
                f"![{p.stem}]({up}{p.relative_to(root).as_posix()})" for p in pngs
            )

        markdown = FIG.sub(figures, markdown)

    def notebook(m: re.Match[str]) -> str:
        root = units["notebook-" + Path(m.group(1)).stem]
        md = (root / "notebook.md").read_text()
        return md.replace("](FIGURES/", f"]({up}generated/figures/")

    markdown = NOTEBOOK.sub(notebook, markdown)
    if "<!-- pmalab-gallery -->" in markdown:
        page_src, folder = GALLERY
        stem = Path(page_src).stem
        d = units[stem] / "generated" / "runs" / stem / folder
        items = []
        for p in sorted(d.glob("*.png")):
            title = re.sub(r"^\d+-", "", p.stem).replace("-", " ")
            items.append(f"### {title}\n\n![{title}]({up}{p.relative_to(units[stem]).as_posix()})")
        markdown = markdown.replace("<!-- pmalab-gallery -->", "\n\n".join(items))
    markdown = markdown.replace("](GENERATED/", f"]({up}generated/")
    return markdown
