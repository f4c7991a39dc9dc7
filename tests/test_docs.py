"""The documentation is tested like code.

* the site builds with ``mkdocs build --strict`` (a broken link, reference or docstring
  fails), and strictness is real: a page with a broken link fails the build;
* every CLI verb has its section in the generated CLI reference; the API reference renders
  the public functions;
* every ``bash`` block of the tutorial pages runs, in order, in an empty directory;
* the README is a landing page (≤ 8,000 characters, opening with the two commands) and its
  Python example runs;
* the notebook tutorial executes top to bottom (nbclient).
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
BIN = str(Path(sys.executable).parent)

pytestmark = pytest.mark.slow


def _env() -> dict[str, str]:
    env = dict(os.environ)
    env["PATH"] = BIN + os.pathsep + env.get("PATH", "")
    env["NO_MKDOCS_2_WARNING"] = "1"
    env["MPLBACKEND"] = "Agg"
    return env


def _mkdocs(config: Path, site: Path) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "-f",
                           str(config), "-d", str(site)], cwd=ROOT, capture_output=True,
                          text=True, env=_env(), timeout=1800)


def _tracked_state() -> str:
    return subprocess.run(["git", "status", "--porcelain", "--untracked-files=all"], cwd=ROOT,
                          capture_output=True, text=True).stdout


@pytest.mark.timeout(1800)  # the first build runs the campaign tutorial and the notebook
def test_site_builds_strictly_with_a_reference_for_every_verb(tmp_path):
    before = _tracked_state()
    p = _mkdocs(ROOT / "mkdocs.yml", tmp_path / "site")
    assert p.returncode == 0, p.stdout + p.stderr
    assert _tracked_state() == before  # the build writes nothing into the tree
    site = tmp_path / "site"
    # the campaign tutorial shows what each command printed and the figures they wrote
    camp = (site / "tutorials" / "campaign" / "index.html").read_text()
    assert camp.count("<pre") >= 8  # 4 command blocks, each followed by its output
    for printed in ("campaign.h5: 10 runs", "validate  campaign.h5:valid-", "Ladder (the error",
                    "wrote improved/identification.json", "report written: report.pdf"):
        assert printed in camp, printed
    assert "viscous-friction" in camp and len(re.findall(r"<img [^>]*generated/", camp)) >= 3
    for src in re.findall(r'<img [^>]*src="([^"]+)"', camp):
        assert (site / "tutorials" / "campaign" / src).resolve().is_file(), src
    # the notebook executed at build, its figure inline
    nb = (site / "tutorials" / "notebook" / "index.html").read_text()
    assert "validation nrmse" in nb and re.search(r"<img [^>]*notebooks/tutorial-1\.png", nb)
    # the gallery: every page of the campaign's report
    gallery = (site / "gallery" / "index.html").read_text()
    assert len(re.findall(r"<img [^>]*report-pages/", gallery)) >= 8
    from pmalab.cli import build_parser

    sub = next(a for a in build_parser()._actions if a.__class__.__name__ == "_SubParsersAction")
    cli = (tmp_path / "site" / "reference" / "cli" / "index.html").read_text()
    for verb in sub.choices:
        assert f"pmalab {verb}</code>" in cli or f"pmalab {verb}" in cli, verb
    api = (tmp_path / "site" / "reference" / "api" / "index.html").read_text()
    # the docstrings' Sphinx roles became links or code, their >>> examples code blocks
    assert not re.search(r":(class|meth|func|mod|attr|data|exc):`", api)
    assert "autorefs-internal" in api and "<blockquote>" not in api
    for name in ("identify", "diagnose", "load", "read_runs", "run_protocol", "load_rig",
                 "import_files", "read_tdms_runs", "read_mat_runs", "residual_shares",
                 "HysteresisLaw", "build_report"):
        assert f'id="{name}' in api or f".{name}" in api, name


@pytest.mark.parametrize("broken, needle", [
    ("[gone](nowhere.md)", "nowhere.md"),
    ("[a cross-reference][pmalab.identify.api.no_such_function]", "no_such_function"),
])
@pytest.mark.timeout(1800)
def test_strict_mode_is_real_a_broken_link_or_reference_fails(tmp_path, broken, needle):
    docs = tmp_path / "docs"
    shutil.copytree(ROOT / "docs", docs)
    shutil.copytree(ROOT / "examples", tmp_path / "examples")  # the notebook page's source
    (docs / "index.md").write_text((docs / "index.md").read_text() + f"\n{broken}\n")
    cfg = (ROOT / "mkdocs.yml").read_text().replace("docs_dir: docs", f"docs_dir: {docs}")
    cfg = cfg.replace("docs/hooks/", f"{docs}/hooks/")
    (tmp_path / "mkdocs.yml").write_text(cfg)
    p = _mkdocs(tmp_path / "mkdocs.yml", tmp_path / "site")
    assert p.returncode != 0 and needle in p.stdout + p.stderr


def _blocks(text: str, lang: str) -> list[str]:
    return re.findall(rf"```{lang}\n(.*?)```", text, flags=re.S)


@pytest.mark.timeout(900)  # a minute or two idle; several on a loaded machine
@pytest.mark.parametrize("page", ["campaign", "import", "control", "bouc-wen-benchmark"])
def test_tutorial_commands_run(page, tmp_path):
    text = (ROOT / "docs" / "tutorials" / f"{page}.md").read_text()
    blocks = _blocks(text, "bash")
    assert blocks, page
    script = "set -euo pipefail\n" + "\n".join(blocks)
    p = subprocess.run(["bash", "-c", script], cwd=tmp_path, capture_output=True, text=True,
                       env=_env(), timeout=600)
    assert p.returncode == 0, p.stdout[-3000:] + p.stderr[-3000:]
    if page == "bouc-wen-benchmark":
        import json

        doc = json.loads((tmp_path / "bw" / "identification.json").read_text())
        assert all(v["rmse_position_m"] <= 1e-5 for v in doc["validation"])
        assert (tmp_path / "sweep-sim.h5").is_file()
    if page == "campaign":
        assert (tmp_path / "report.pdf").stat().st_size > 10_000
        assert "viscous-friction" in (tmp_path / "diag" / "diagnosis.json").read_text()


def test_readme_is_a_landing_page():
    text = (ROOT / "README.md").read_text()
    assert len(text) <= 8000, len(text)
    first = _blocks(text, "sh")[0]
    assert first.splitlines()[0].startswith("make demo") and "make test" in first
    assert (ROOT / "docs" / "assets" / "loop.png").exists()


def test_notebook_runs_top_to_bottom():
    import nbclient
    import nbformat

    nb = nbformat.read(ROOT / "examples" / "tutorial.ipynb", as_version=4)
    nbclient.NotebookClient(nb, timeout=600, kernel_name="python3").execute()
    out = "".join(o.get("text", "") for c in nb.cells if c.cell_type == "code"
                  for o in c.get("outputs", []))
    assert "viscous-friction" in out and "validation nrmse" in out
    # the ladder's figure shows inline (a Jupyter user sees it; the site renders it)
    assert any("image/png" in o.get("data", {}) for c in nb.cells if c.cell_type == "code"
               for o in c.get("outputs", []))


def test_index_page_says_what_the_readme_says():
    """The site's landing page and the README describe the same tool: the same "What it is
    for" section (the figure is the build's copy on the site)."""
    def section(text: str) -> str:
        i = text.index("## What it is for")
        return text[i:text.index("\n## ", i + 5)]

    readme = section((ROOT / "README.md").read_text())
    index = section((ROOT / "docs" / "index.md").read_text())
    assert index.replace("](generated/figures/loop.png)", "](docs/assets/loop.png)").replace(
        "`docs/make_figures.py` at build)", "`docs/make_figures.py`)") == readme
    assert "Bouc-Wen or Duhem" not in index


def test_docstring_roles_become_references_or_code_and_examples_code_blocks():
    import importlib.util

    spec = importlib.util.spec_from_file_location("sphinx_roles",
                                                  ROOT / "docs" / "hooks" / "sphinx_roles.py")
    assert spec is not None and spec.loader is not None
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    text = "The notebook API.\n\n>>> runs = load('c.h5')\n>>> len(runs)\n3\n\nMore text."
    out = mod.fence_doctests(text)
    assert "```python\n>>> runs = load('c.h5')\n>>> len(runs)\n3\n```" in out
    assert out.endswith("More text.")
    exact, prefixes = mod.rendered_paths()
    assert "pmalab.identify.api.load" in exact and "pmalab.runfile.Run." in prefixes
    ext = mod.SphinxRoles()
    ext._documented = lambda path: True  # the package is not loaded in this test
    obj = type("O", (), {"parent": None})()
    done = ext.rewrite(obj, "See :func:`pmalab.identify.api.load` and :class:`~pmalab.x.Gone`.")
    assert done == "See [`pmalab.identify.api.load()`][pmalab.identify.api.load] and `Gone`."
