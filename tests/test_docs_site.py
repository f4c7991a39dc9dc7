"""The documentation site, built strictly as ``make docs`` builds it.

* the build succeeds with ``--strict`` and writes nothing into the tree; strictness is real:
  a broken link or an unresolved cross-reference fails it;
* every CLI verb has its section in the generated CLI reference; the API reference renders
  the public functions, with no raw Sphinx role left;
* every tutorial page (and the rig-file how-to) shows each command's output and the
  figures the commands wrote (the build ran them in an empty directory: their files are
  checked here), the notebook
  executed with its figure inline (the build ran it: its outputs are checked here), and the
  gallery every page of the tutorial's report.
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from docs_hook import show_hook

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
    return subprocess.run([*_lower_priority(), sys.executable, "-m", "mkdocs", "build",
                           "--strict", "-f", str(config), "-d", str(site)], cwd=ROOT,
                          capture_output=True, text=True, env=_env(), timeout=1800)


def _lower_priority() -> list[str]:
    """Under xdist on an otherwise idle machine, the build (and every command it runs) at
    nice 10.  The build makes its tutorial units several processes at once, and the suite
    starts it beside the other worker's emulator and real-time tests (conftest's
    ``WAITING``), which mostly wait: at a lower priority the build takes the core they leave
    idle and gives it back as soon as a recording or an emulator wakes up, so they keep
    running as on an idle machine.  Not 19: the build runs an emulated rig itself (the
    rig-file page), which must still answer within its rig file's reply timeout when the
    other worker keeps both cores busy.  Not on a machine already busy with other work
    (load average at or above the cores + 1): there no core is idle to fill, and a lower
    priority only hands the build's share to that work (a build so starved at load 15 took
    over 18 minutes).  Run alone, the build keeps the priority it was given.  The build's
    output is the same at any priority."""
    nice = shutil.which("nice")
    if not nice or not os.environ.get("PYTEST_XDIST_WORKER"):
        return []
    try:
        # the cores this process may run on (a container's cgroup/affinity, not the host's)
        cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else None
        idle = os.getloadavg()[0] < (cores or os.cpu_count() or 1) + 1
    except OSError:  # no load average here
        idle = False
    return [nice, "-n", "10"] if idle else []


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
    # every page the build runs: each command followed by its output, the figures its
    # commands wrote shown (and present in the site)
    for page in show_hook().RUN_PAGES:
        html = (site / page.removesuffix(".md") / "index.html").read_text()
        imgs = re.findall(r'<img [^>]*src="([^"]+generated/runs/[^"]+)"', html)
        assert imgs, page
        for src in imgs:
            assert (site / page.removesuffix(".md") / src).resolve().is_file(), (page, src)
        assert html.count('class="language-text') >= 1, page  # what the commands printed
    # what the tutorials' commands wrote, in the empty directories the build ran them in
    cache = show_hook().built()  # where the build ran each page, the notebook, the figures
    work = cache["campaign"] / "generated" / "runs" / "campaign"
    assert (work / "report.pdf").stat().st_size > 10_000
    assert "viscous-friction" in (work / "diag" / "diagnosis.json").read_text()
    import json

    bw = cache["bouc-wen-benchmark"] / "generated" / "runs" / "bouc-wen-benchmark"
    doc = json.loads((bw / "bw" / "identification.json").read_text())
    assert all(v["rmse_position_m"] <= 1e-5 for v in doc["validation"])  # the page's claim
    assert (bw / "sweep-sim.h5").is_file()
    oring = cache["import"] / "generated" / "runs" / "import"
    assert json.loads((oring / "diag-real" / "diagnosis.json").read_text())["ladder"]
    rig = (site / "how-to" / "rig-file" / "index.html").read_text()
    assert "the two raw values must differ" in rig and "exit status 2" in rig
    assert "try.h5: 1 runs" in rig and "vented (confirmed" in rig
    # the notebook, executed top to bottom by the build (nbclient)
    nb_md = (cache["notebook-tutorial"] / "notebook.md").read_text()
    assert "viscous-friction" in nb_md and "validation nrmse" in nb_md
    assert "notebooks/tutorial-1.png" in nb_md  # the ladder's figure, shown inline
    # what a reader sees at a laptop's width: nothing clipped, every figure loaded
    pages = [pg.removesuffix(".md") for pg in show_hook().RUN_PAGES]
    figures = _check_in_a_browser(site, [*pages, "tutorials/notebook", "gallery",
                                         "reference/api", "reference/cli", ""])
    assert all(figures[pg] >= 1 for pg in [*pages, "tutorials/notebook"]), figures
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


#: in the browser: every code block, output and table of the page's text column shows its
#: whole width (nothing clipped behind a horizontal scroll bar), every figure has loaded and
#: is no wider than the column
_FITS = """(() => {
  const col = document.querySelector('.md-content');
  const bad = [];
  for (const el of col.querySelectorAll('pre, pre > code, table, .md-typeset__scrollwrap')) {
    if (el.scrollWidth > el.clientWidth + 1)
      bad.push(el.tagName + ' ' + el.scrollWidth + '>' + el.clientWidth + ': '
               + el.textContent.slice(0, 60));
  }
  const imgs = [...col.querySelectorAll('img')];
  for (const im of imgs) {
    if (!im.complete || im.naturalWidth === 0) bad.push('not loaded: ' + im.src);
    else if (im.getBoundingClientRect().width > col.clientWidth + 1) bad.push('wide: ' + im.src);
  }
  return JSON.stringify({bad: bad, images: imgs.length});
})()"""


def _check_in_a_browser(site: Path, pages: list[str]) -> dict[str, int]:
    """Open each page in headless Chromium at a laptop's width (1366 CSS px); return the
    number of figures per page, failing on anything clipped or not loaded."""
    import json

    from cdp import Browser, chromium

    exe = chromium()
    if exe is None:
        pytest.skip("no chromium (make test installs it)")
    figures = {}
    with Browser(exe, width=1366, height=900) as b:
        for page in pages:
            b.navigate((site / page / "index.html").as_uri())
            b.wait_for("document.readyState === 'complete' && "
                       "[...document.images].every(i => i.complete)", 60, f"{page} to load")
            got = json.loads(str(b.evaluate(_FITS)))
            assert got["bad"] == [], (page, got["bad"])
            figures[page] = got["images"]
    return figures


@pytest.mark.timeout(1800)
def test_strict_mode_is_real_a_broken_link_or_reference_fails(tmp_path):
    """The strict build fails on a broken link, an unresolved cross-reference on a page, and
    a docstring's role naming nothing (a typo, a renamed object: a copy of the package whose
    ``load`` names a function that does not exist; code unchanged, so the build's cached
    tutorial outputs serve).  One build with the three mistakes: each is a warning of its
    own, and one warning fails a strict build."""
    docs = tmp_path / "docs"
    shutil.copytree(ROOT / "docs", docs)
    shutil.copytree(ROOT / "examples", tmp_path / "examples")  # the notebook page's source
    (docs / "index.md").write_text((docs / "index.md").read_text() + "\n[gone](nowhere.md)\n"
                                   "\n[a cross-reference][pmalab.identify.api.no_such_page_ref]\n")
    shutil.copytree(ROOT / "pmalab", tmp_path / "src" / "pmalab",
                    ignore=shutil.ignore_patterns("__pycache__"))
    api = tmp_path / "src" / "pmalab" / "identify" / "api.py"
    text = api.read_text()
    anchor = "    Parameters\n    ----------\n    *paths\n"
    assert anchor in text
    api.write_text(text.replace(
        anchor, f"    See :func:`pmalab.identify.api.no_such_docstring_ref`.\n\n{anchor}", 1))
    cfg = (ROOT / "mkdocs.yml").read_text().replace("docs_dir: docs", f"docs_dir: {docs}")
    cfg = cfg.replace("docs/hooks/", f"{docs}/hooks/")
    cfg = cfg.replace("        python:\n", f"        python:\n          paths: [{tmp_path / 'src'}]\n",
                      1)
    assert f"paths: [{tmp_path / 'src'}]" in cfg
    (tmp_path / "mkdocs.yml").write_text(cfg)
    p = _mkdocs(tmp_path / "mkdocs.yml", tmp_path / "site")
    assert p.returncode != 0
    warnings = [ln for ln in (p.stdout + p.stderr).splitlines() if ln.startswith("WARNING")]
    for needle in ("nowhere.md", "no_such_page_ref", "no_such_docstring_ref"):
        assert any(needle in ln for ln in warnings), (needle, warnings)


