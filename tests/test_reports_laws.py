"""The report of several laws identified on the same runs (``pmalab identify --model a,b,c``
then ``pmalab report OUT``): the ranking page with every held-out run's error per law on one
scale, and each separating held-out run's loops law beside law on ONE error colour scale
with the residuals on ONE shared axis; the best law's own pages follow.

The campaign is the simulated muscle whose braid friction is Maxwell-slip-shaped
(data/truth/hysteresis-maxwell-slip.toml), so the laws really differ (Maxwell-slip ≈ 1.1×
the noise floor, Bouc-Wen ≈ 1.9×).
"""

from __future__ import annotations

import contextlib
import io
import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from matplotlib.collections import LineCollection
from shared_work import FOUR_LAWS, maxwell_slip_four_laws

from pmalab.cli import main as pmalab_main
from pmalab.reports import ReportError, load_report_dir, plan_pages
from pmalab.reports.build import draw_page
from pmalab.reports.figures_laws import run_floor
from pmalab.reports.layout import page_problems

LAWS = list(FOUR_LAWS)


def _cli(argv: list[str]) -> tuple[int, str]:
    out = io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(out):
        rc = pmalab_main(argv)
    return rc, out.getvalue()


@pytest.fixture(scope="module")
def laws_dir(tmp_path_factory) -> Path:
    """``pmalab identify c.h5 --model bouc-wen,duhem,prandtl-ishlinskii,maxwell-slip`` of the
    Maxwell-slip-shaped muscle's diagnosis-test campaign (made once in a test session:
    test_laws_elements checks the same identification)."""
    return maxwell_slip_four_laws(tmp_path_factory)[1]


def test_laws_pages_rank_the_laws_and_draw_them_on_one_scale(laws_dir):
    data = load_report_dir(laws_dir)
    table = json.loads((laws_dir / "laws.json").read_text())
    best = table["laws"][0]["law"]
    # the best law is the report's identification; every law is read, best first
    assert data.identification is not None and data.identification["model"] == best
    assert [e.law for e in data.laws] == [r["law"] for r in table["laws"]]
    pages = plan_pages(data)
    titles = [p.title for p in pages]
    assert titles[1].startswith("Hysteresis laws compared on the held-out runs")
    loops = [i for i, t in enumerate(titles) if t.startswith("Loops of every law")]
    # one loops page per held-out run (two here), before the best law's own pages
    assert len(loops) == 2 and loops == [2, 3], titles
    assert any(t.startswith("Parameters against muscle pressure") for t in titles[4:])

    fig = draw_page(pages[1], data, 2, len(pages))
    assert page_problems(fig) == []
    bars = [p for ax in fig.axes for p in ax.patches]
    # a bar per (law, held-out run), its height the run's nrmse over the run's own floor
    expect = sorted(
        t.nrmse / run_floor(t) for e in data.laws for t in e.validation()  # type: ignore[operator]
    )
    np.testing.assert_allclose(sorted(b.get_height() for b in bars), expect, rtol=1e-9)

    for i in loops:
        fig = draw_page(pages[i], data, i + 1, len(pages))
        assert page_problems(fig) == []
        loop_axes = [ax for ax in fig.axes if ax.get_xlabel().startswith("Contraction")]
        cols = [c for ax in loop_axes for c in ax.collections if isinstance(c, LineCollection)]
        assert len(cols) == len(LAWS)
        # ONE colour scale: every law's loop is coloured against the same |error| range
        assert len({(c.norm.vmin, c.norm.vmax) for c in cols}) == 1
        # ... and the residual panels share one axis that holds every law's residual
        res_axes = [ax for ax in fig.axes if ax.get_xlabel().startswith("Time")]
        assert len(res_axes) == len(LAWS)
        assert len({ax.get_ylim() for ax in res_axes}) == 1
        top = res_axes[0].get_ylim()[1]
        worst = max(float(np.max(np.abs(t.error))) for e in data.laws for t in e.validation()
                    if pages[i].title.endswith(t.run))
        assert top >= worst


def test_report_of_a_laws_directory_from_the_shell(laws_dir, tmp_path):
    out = tmp_path / "laws.pdf"
    rc, text = _cli(["report", str(laws_dir), "--out", str(out), "-q"])
    assert rc == 0, text
    assert out.read_bytes()[:5] == b"%PDF-" and out.stat().st_size > 50_000


def test_laws_directory_refusals(laws_dir, tmp_path):
    # beside another identification: one line, which directory and what to do
    with pytest.raises(ReportError, match="give the laws directory alone"):
        load_report_dir([laws_dir, laws_dir / "bouc-wen"])
    # a law's directory pruned after identify: the line names laws.json's entry
    pruned = tmp_path / "pruned"
    shutil.copytree(laws_dir, pruned)
    shutil.rmtree(pruned / "duhem")
    with pytest.raises(ReportError, match=r"laws\[\d\] \(duhem\): .* is missing"):
        load_report_dir(pruned)
    rc, text = _cli(["report", str(pruned), "--out", str(tmp_path / "r.pdf")])
    assert rc != 0 and "duhem" in text and "Traceback" not in text
    assert not (tmp_path / "r.pdf").exists()
