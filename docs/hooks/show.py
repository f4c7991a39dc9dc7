"""MkDocs hook: the pages show what the user will see, made by the build.

* **Tutorial output.**  A tutorial page listed in :data:`RUN_PAGES` has its ``bash`` blocks
  run, in order, in an empty directory (as the test suite runs them); each block is
  followed on the page by what it printed (a ``text`` block), and a line
  ``<!-- pmalab-figures: GLOB -->`` becomes the PNG figures the commands wrote that match
  ``GLOB`` (relative to the directory the commands ran in).
* **The notebook.**  ``<!-- pmalab-notebook: PATH -->`` becomes the notebook executed at
  build (nbclient): its markdown, its code and every output, figures inline.
* **Figures.**  ``docs/make_figures.py``'s figures (``figures/loop.png``) and the report
  pages of the campaign tutorial (the gallery page: ``<!-- pmalab-gallery -->``).

Everything is generated into a cache directory keyed by the hash of pmalab's sources, the
pages and the scripts (``$XDG_CACHE_HOME/pmalab/docs``), and added to the site as
generated files: the build writes nothing into the tree (``make docs`` leaves it clean), a
second build with unchanged sources costs nothing, and a change of the code makes them
again.
"""

from __future__ import annotations

import base64
import hashlib
import json
import os
import re
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

from mkdocs.structure.files import File, Files

DOCS = Path(__file__).resolve().parents[1]
#: tutorial pages whose commands the build runs (the rest show their commands only)
RUN_PAGES = ("tutorials/campaign.md",)
#: the tutorial whose report pages make the gallery, and where its commands write them
GALLERY = ("tutorials/campaign.md", "report-pages")
#: ``<!-- pmalab-figures: GLOB -->``: the PNGs the page's commands wrote matching GLOB
FIG = re.compile(r"^<!-- pmalab-figures: (\S+) -->$", re.M)
NOTEBOOK = re.compile(r"^<!-- pmalab-notebook: (\S+) -->$", re.M)
BASH = re.compile(r"```bash\n(.*?)```\n", re.S)
OUTPUT_LINES = 60  # a block's output is cut to this many lines (with a note)

#: part of the cache key: raise it when what :func:`_make` makes changes (the rest of the
#: key is the hash of pmalab's sources, the run pages' commands, the notebooks and
#: make_figures.py)
CACHE_VERSION = "1"

_state: dict[str, Path] = {}


# --------------------------------------------------------------------------- the cache
def _key() -> str:
    import pmalab

    h = hashlib.sha256()
    src = Path(pmalab.__file__).parent
    for p in sorted(src.rglob("*")):
        if p.suffix in (".py", ".toml", ".json") and "__pycache__" not in p.parts:
            h.update(str(p.relative_to(src)).encode())
            h.update(p.read_bytes())
    h.update(CACHE_VERSION.encode())
    for page in RUN_PAGES:  # the commands, not the prose around them
        h.update("\n".join(BASH.findall((DOCS / page).read_text(encoding="utf-8"))).encode())
    h.update((DOCS / "make_figures.py").read_bytes())
    for nb in _notebooks():
        h.update(nb.read_bytes())
    return h.hexdigest()[:16]


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


def _make(out: Path) -> None:
    """Run the tutorials, the notebooks and the figure script into ``out``."""
    outputs: dict[str, list[str]] = {}
    for page in RUN_PAGES:
        work = out / "generated" / "runs" / Path(page).stem
        work.mkdir(parents=True)
        texts = []
        for block in BASH.findall((DOCS / page).read_text(encoding="utf-8")):
            p = subprocess.run(
                ["bash", "-c", "set -euo pipefail\n" + block],
                cwd=work,
                capture_output=True,
                text=True,
                env=_env(),
                timeout=1800,
            )
            if p.returncode != 0:
                raise RuntimeError(f"{page}: a command failed:\n{block}\n{p.stderr[-2000:]}")
            texts.append(p.stdout + p.stderr)
        outputs[page] = texts
    (out / "outputs.json").write_text(json.dumps(outputs, indent=1))
    for nb in _notebooks():
        (out / "notebooks").mkdir(exist_ok=True)
        md = _notebook_markdown(nb, out / "generated" / "figures" / "notebooks", nb.stem)
        (out / "notebooks" / f"{nb.stem}.md").write_text(md)
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


def built() -> Path:
    """The cache directory for the current sources, made when missing."""
    if "dir" in _state:
        return _state["dir"]
    final = _cache_root() / _key()
    if not (final / "done").exists():
        final.parent.mkdir(parents=True, exist_ok=True)
        tmp = Path(tempfile.mkdtemp(prefix="making-", dir=final.parent))
        try:
            _make(tmp)
            (tmp / "done").write_text("")
            if final.exists():
                shutil.rmtree(final, ignore_errors=True)
            os.replace(tmp, final)
        except FileExistsError:  # another build made it meanwhile
            shutil.rmtree(tmp, ignore_errors=True)
        except BaseException:
            shutil.rmtree(tmp, ignore_errors=True)
            raise
    _state["dir"] = final
    _prune(final.parent, keep=8)
    return final


def _prune(root: Path, keep: int) -> None:
    """Remove all but the ``keep`` most recently made builds (older sources' outputs)."""
    done = sorted(
        (d for d in root.iterdir() if (d / "done").exists()),
        key=lambda d: (d / "done").stat().st_mtime,
        reverse=True,
    )
    for old in done[keep:]:
        shutil.rmtree(old, ignore_errors=True)


# --------------------------------------------------------------------------- the hooks
def _figures(root: Path) -> list[Path]:
    """Every PNG the build made (``generated/``: figures/… and the tutorials' folders)."""
    return sorted((root / "generated").rglob("*.png"))


def _site_path(root: Path, png: Path) -> str:
    return png.relative_to(root).as_posix()  # generated/...


def on_files(files: Files, config) -> Files:
    root = built()
    for png in _figures(root):
        files.append(
            File(
                png.relative_to(root).as_posix(),
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
    root = built()
    up = _up(src)
    if src in RUN_PAGES:
        outputs = json.loads((root / "outputs.json").read_text())[src]
        it = iter(outputs)

        def with_output(m: re.Match[str]) -> str:
            text = next(it, "").strip()
            shown = f"\n```text\n{_cut(text)}\n```\n" if text else ""
            return m.group(0) + shown

        markdown = BASH.sub(with_output, markdown)

        def figures(m: re.Match[str]) -> str:
            pngs = sorted((root / "generated" / "runs" / Path(src).stem).glob(m.group(1)))
            return "\n\n".join(
                f"![{p.stem}]({up}{_site_path(root, p)})" for p in pngs
            ) or "*(no figures)*"

        markdown = FIG.sub(figures, markdown)

    def notebook(m: re.Match[str]) -> str:
        stem = Path(m.group(1)).stem
        md = (root / "notebooks" / f"{stem}.md").read_text()
        return md.replace("](FIGURES/", f"]({up}generated/figures/")

    markdown = NOTEBOOK.sub(notebook, markdown)
    if "<!-- pmalab-gallery -->" in markdown:
        page_src, folder = GALLERY
        d = root / "generated" / "runs" / Path(page_src).stem / folder
        items = []
        for p in sorted(d.glob("*.png")):
            title = re.sub(r"^\d+-", "", p.stem).replace("-", " ")
            items.append(f"### {title}\n\n![{title}]({up}{_site_path(root, p)})")
        markdown = markdown.replace("<!-- pmalab-gallery -->", "\n\n".join(items))
    markdown = markdown.replace("](GENERATED/", f"]({up}generated/")
    return markdown
