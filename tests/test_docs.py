"""The documentation is tested like code (the site build itself: test_docs_site.py).

* every ``bash`` block of the tutorial pages runs, in order, in an empty directory (the
  campaign tutorial's are run by the documentation build, which shows their output);
* the README is a landing page (≤ 8,000 characters, opening with the two commands; its
  Python example runs alone: test_first_hour.py) and the site's index page says what it says;
* the docstrings' Sphinx roles become cross-references or code, their examples code blocks.
"""

from __future__ import annotations

import os
import re
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




def _blocks(text: str, lang: str) -> list[str]:
    return re.findall(rf"```{lang}\n(.*?)```", text, flags=re.S)


# the campaign tutorial's commands are run by the documentation build, which fails when one
# fails; test_docs_site checks what they wrote
@pytest.mark.timeout(900)  # a minute or two idle; several on a loaded machine
@pytest.mark.parametrize("page", ["import", "control", "bouc-wen-benchmark"])
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


def test_readme_is_a_landing_page():
    text = (ROOT / "README.md").read_text()
    assert len(text) <= 8000, len(text)
    first = _blocks(text, "sh")[0]
    assert first.splitlines()[0].startswith("make demo") and "make test" in first
    assert (ROOT / "docs" / "assets" / "loop.png").exists()


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
