"""The whole chain on real measurements nobody on the team made (data/real/zillen-oring257:
a 3D-printed pneumatic actuator's friction tests, CC0, see PROVENANCE.md there).

Headerless LabVIEW-style text (tab, CRLF) → one campaign in one command (each record split
in halves: identify on the first, validate on the second) → diagnose → identify with what
the ladder added → report.  What pmalab says is checked here, not only by eye:

* the import holds the file's numbers exactly (unit conversions only);
* the base model sits far above the record's noise floor and the ladder climbs: every step
  lowers the held-out error of every held-out run, and the last step ends ≥ 20 % below the
  base model;
* diagnose's final number is what `pmalab identify --add ...` reports on the same runs;
* what is left is located (the share tied to the loop, above the band, offset).

The import, the diagnosis and the report are the import tutorial's commands
(docs/tutorials/import.md, checked here to be these), as the documentation build ran them
in an empty directory (docs/hooks/show.py's cache: made here if no build has made them for
this code yet, once for both).
"""

from __future__ import annotations

import contextlib
import io
import itertools
import json
import shlex
from pathlib import Path

import numpy as np
import pytest
from docs_hook import show_hook

from pmalab.cli import main as pmalab_main
from pmalab.identify.api import load
from pmalab.paths import DATA_DIR

ROOT = Path(__file__).resolve().parents[1]
REAL = DATA_DIR / "real" / "zillen-oring257"
FILES = sorted(REAL.glob("O-ring257_*bar.csv"))
IMPORT = ["--no-header", "--delimiter", "\\t", "--columns", "time,-,-,-,position,pressure,force",
          "--units", "time=ms,pressure=bar", "--negate", "position",
          "--pressure-from-name", r"(\d+)bar", "--split-halves", "--frequency", "auto",
          "--waveform", "triangle"]


def _cli(args: list[str]) -> tuple[int, str, str]:
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = pmalab_main(args)
    return code, out.getvalue(), err.getvalue()


def _commands(block: str) -> list[list[str]]:
    """A bash block's commands, each split into its words (continued lines joined)."""
    return [shlex.split(ln) for ln in block.replace("\\\n", " ").splitlines() if ln.strip()]


@pytest.fixture(scope="module")
def tutorial(tmp_path_factory) -> tuple[Path, list[str]]:
    """The import tutorial's work directory as the documentation build left it, and what
    each of its command blocks printed; its commands are checked to be the chain above:
    the shipped files copied, imported with :data:`IMPORT`, diagnosed, reported."""
    assert len(FILES) == 4 and (REAL / "LICENSE").exists() and (REAL / "PROVENANCE.md").exists()
    show = show_hook()
    page = "tutorials/import.md"
    assert page in show.RUN_PAGES
    blocks = [_commands(b) for b in show.BASH.findall((ROOT / "docs" / page).read_text())]
    assert len(blocks) == 2, blocks
    (cp, imp), (diag, report) = blocks
    assert cp[:2] == ["cp", "-r"] and cp[2].endswith("/real/zillen-oring257"), cp
    assert imp == ["pmalab", "import", "zillen-oring257/O-ring257_*bar.csv", *IMPORT,
                   "--out", "oring.h5"], imp
    assert diag == ["pmalab", "diagnose", "oring.h5", "--model", "bouc-wen", "--out",
                    "diag-real", "--quiet"], diag
    assert report[:5] == ["pmalab", "report", "diag-real", "--out", "oring.pdf"], report
    root = show.unit_copy("import", tmp_path_factory.mktemp("docs-unit") / "import")
    printed = json.loads((root / "outputs.json").read_text())
    return root / "generated" / "runs" / "import", printed


@pytest.fixture(scope="module")
def campaign(tutorial) -> Path:
    work, printed = tutorial
    assert "8 runs from 4 file(s)" in printed[0] and "4 held out" in printed[0], printed[0]
    return work / "oring.h5"


def test_import_keeps_the_files_numbers(campaign):
    runs = {r.name: r for r in load(campaign)}
    assert sorted(runs) == sorted(f"{f.stem}-{h}" for f in FILES for h in "ab")
    for f in FILES:
        raw = np.loadtxt(f, delimiter="\t")
        a, b = runs[f"{f.stem}-a"], runs[f"{f.stem}-b"]
        assert a.attrs["role"] == "identification" and b.attrs["role"] == "validation"
        assert len(a) + len(b) == len(raw)  # every sample kept, in exactly one half
        for run, rows in ((a, raw[: len(a)]), (b, raw[len(a):])):
            np.testing.assert_allclose(run.time, rows[:, 0] / 1000.0, rtol=0, atol=1e-12)
            np.testing.assert_allclose(run.position, -rows[:, 4], rtol=0, atol=1e-12)
            np.testing.assert_allclose(run.force, rows[:, 6], rtol=0, atol=1e-12)
            np.testing.assert_allclose(run.muscle_pressure, rows[:, 5] * 0.1, rtol=1e-12)
        bar = int(f.stem.split("_")[1].removesuffix("bar"))
        assert a.nominal_pressure == pytest.approx(bar * 0.1)
        # the excitation frequency read off the spectrum: the tests ran at 0.1-0.2 Hz
        assert 0.08 < a.frequency < 0.25


@pytest.fixture(scope="module")
def diagnosis(tutorial) -> dict:
    work, _ = tutorial
    return json.loads((work / "diag-real" / "diagnosis.json").read_text())


def test_ladder_climbs_on_real_data_every_step_improving_every_held_out_run(diagnosis):
    ladder = diagnosis["ladder"]
    floor = diagnosis["noise_floor"]["mean_nrmse"]
    base, last = ladder[0]["nrmse"], ladder[-1]["nrmse"]
    assert base > 5 * floor  # a real device: far above its noise floor
    assert len(ladder) >= 3, diagnosis["summary"]  # at least two modest effects added
    assert ladder[1]["added"] == "pressure-variation"  # -44 % here, far beyond its ± 17
    for prev, step in itertools.pairwise(ladder):
        assert all(a < b for a, b in zip(step["per_run"], prev["per_run"])), step
    assert last <= 0.8 * base
    assert diagnosis["verdict"] == "unexplained"
    rest = diagnosis["residual"]
    assert rest["next"] == "loop" and "Where the rest lies" in diagnosis["summary"]


def test_readme_tells_what_the_ladder_does_on_real_data(diagnosis):
    # the README's paragraph on these measurements names the steps and the fall as they are
    readme = (ROOT / "README.md").read_text()
    para = readme[readme.index("`data/real/zillen-oring257/`"):]
    para = " ".join(para[: para.index("\n\n")].split())
    ladder = diagnosis["ladder"]
    steps = [s["added"].replace("-", " ") for s in ladder[1:] if s["added"]]
    assert steps and all(s in para for s in steps), (steps, para)
    assert [para.index(s) for s in steps] == sorted(para.index(s) for s in steps), para
    for law in {s.get("law") for s in ladder[1:]} - {ladder[0].get("law")}:
        assert law.replace("-", " ") in para.lower().replace("-", " "), (law, para)
    fall = round(100 * (1 - ladder[-1]["nrmse"] / ladder[0]["nrmse"]))
    assert f"−{fall} % in all" in para, (fall, para)


def test_diagnose_numbers_are_identifys(diagnosis, campaign, tmp_path):
    adds = [a for s in diagnosis["ladder"][1:] for a in ("--add", s["added"]) if s["added"]]
    law = diagnosis["final_law"]
    out = tmp_path / "ident"
    code, _, err = _cli(["identify", str(campaign), "--model", law, *adds, "--out", str(out),
                         "--quiet"])
    assert code == 0, err
    ident = json.loads((out / "identification.json").read_text())
    got = float(np.mean([v["nrmse"] for v in ident["validation"]]))
    assert got == pytest.approx(diagnosis["ladder"][-1]["nrmse"], rel=0.02)


def test_report_of_the_real_diagnosis(tutorial):
    import pypdfium2

    work, _ = tutorial
    pdf = work / "oring.pdf"  # `pmalab report diag-real --out oring.pdf`
    assert len(pypdfium2.PdfDocument(str(pdf))) >= 2
