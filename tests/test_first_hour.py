"""What a new user meets in the first hour tells the truth: the help names what exists,
``--quiet`` is quiet, a wrong name lists the shipped choices, the report's title page
lists each run once under its role, and the README's Python example runs on its own."""

from __future__ import annotations

import contextlib
import io
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest
from identify_synth import make_run
from reports_fixtures import write_diagnosis_dir, write_identification_dir

from pmalab.cli import REGISTRY_PLACEHOLDERS
from pmalab.cli import main as pmalab_main
from pmalab.control.controllers import CONTROLLERS
from pmalab.identify.effects import EFFECTS
from pmalab.identify.laws import LAWS
from pmalab.identify.laws.duhem import Duhem
from pmalab.paths import PROTOCOLS_DIR, RIGS_DIR, TRUTH_DIR, shipped_names
from pmalab.runfile import write_runs

ROOT = Path(__file__).resolve().parents[1]


def _cli(args) -> tuple[int, str, str]:
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = pmalab_main([str(a) for a in args])
    return code, out.getvalue(), err.getvalue()


def _help(*verb: str) -> str:
    code, out, _ = _cli([*verb, "--help"])
    assert code == 0
    return " ".join(out.split())  # argparse wraps at the terminal width


# ------------------------------------------------------------------ help from the registries
def test_help_names_every_registered_law_effect_controller_and_shipped_protocol():
    top = _help()
    assert "Bouc-Wen or Duhem" not in top
    line = next(ln for ln in top.split("identify ")[1:] if ln.startswith("fit"))
    assert all(law in line for law in LAWS), line
    ident = _help("identify")
    assert all(law in ident for law in LAWS) and all(e in ident for e in EFFECTS)
    assert all(law in _help("diagnose") for law in LAWS)
    assert all(c in _help("control") for c in CONTROLLERS)
    run = _help("run")
    assert all(p in run for p in shipped_names(PROTOCOLS_DIR))
    assert all(r in run for r in shipped_names(RIGS_DIR))
    assert not any(k in run + ident + top for k in REGISTRY_PLACEHOLDERS)  # all filled


def test_help_reads_the_ids_the_registries_hold_without_loading_them():
    from pmalab.registry import declared_ids

    pkg = ROOT / "pmalab"
    assert declared_ids(pkg / "identify" / "laws") == list(LAWS)
    assert declared_ids(pkg / "identify" / "effects", "id") == list(EFFECTS)
    assert declared_ids(pkg / "control") == list(CONTROLLERS)
    # a fresh `pmalab --help` (no registry loaded) names them all, and loads no numpy
    code = ("import sys\nfrom pmalab.cli import main\ntry:\n    main(['identify', '--help'])\n"
            "except SystemExit:\n    pass\nprint('numpy' in sys.modules)\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True, cwd=ROOT).stdout
    flat = " ".join(out.split())
    assert flat.endswith("False") and all(x in flat for x in [*LAWS, *EFFECTS]), flat


def test_help_is_generated_a_new_law_appears_in_it():
    class Hysteron(Duhem):
        name = "test-hysteron"

    LAWS.register("test-hysteron", Hysteron)
    try:
        assert "test-hysteron" in _help() and "test-hysteron" in _help("identify")
    finally:
        LAWS.unregister("test-hysteron")
    assert "test-hysteron" not in _help()


def test_ids_are_never_split_at_their_hyphens():
    code, out, _ = _cli(["--help"])
    assert code == 0 and not re.search(r"prandtl-\n", out)


# ------------------------------------------------------------------ unknown names
@pytest.mark.parametrize("args, shipped", [
    (["run", "--rig", "sim", "--protocol", "nope", "--out", "{d}/o.h5"],
     shipped_names(PROTOCOLS_DIR)),
    (["run", "--rig", "nope", "--protocol", "quick", "--out", "{d}/o.h5"],
     ["sim", *shipped_names(RIGS_DIR)]),
    (["control", "--controller", "pid", "--truth", "nope", "--reference", "square:0.1Hz:15mm",
      "--duration", "1", "--out", "{d}/c.h5"], shipped_names(TRUTH_DIR)),
    (["control", "--controller", "nope", "--reference", "square:0.1Hz:15mm", "--duration", "1",
      "--out", "{d}/c.h5"], list(CONTROLLERS)),
    (["identify", "{d}/c.h5", "--model", "nope", "--out", "{d}/o"], list(LAWS)),
    (["identify", "{d}/c.h5", "--model", "bouc-wen", "--add", "nope", "--out", "{d}/o"],
     list(EFFECTS)),
])
def test_an_unknown_name_is_one_line_listing_the_shipped_choices(tmp_path, args, shipped):
    d = tmp_path / "w"
    d.mkdir()
    if args[0] == "identify":
        write_runs(d / "c.h5", [make_run("bouc-wen", 0.4, n=2000)[0]])
    before = set(d.iterdir())
    code, _out, err = _cli([a.replace("{d}", str(d)) for a in args])
    assert code != 0 and err.count("\n") == 1 and "Traceback" not in err, err
    assert "nope" in err and all(name in err for name in shipped), err
    assert set(d.iterdir()) == before  # a failed command leaves nothing behind


# ------------------------------------------------------------------ --quiet
@pytest.fixture(scope="module")
def campaign(tmp_path_factory) -> Path:
    runs = [make_run("bouc-wen", p, n=3000, seed=i)[0] for i, p in enumerate((0.3, 0.45, 0.6))]
    held, _ = make_run("bouc-wen", 0.5, n=3000, seed=9, name="held-500kPa")
    held.attrs["role"] = "validation"
    path = tmp_path_factory.mktemp("quiet") / "c.h5"
    write_runs(path, [*runs, held])
    return path


def test_quiet_identify_prints_only_the_line_naming_its_outputs(campaign, tmp_path):
    code, loud, _ = _cli(["identify", campaign, "--model", "bouc-wen", "--out", tmp_path / "a",
                          "--jobs", "1"])
    assert code == 0 and len(loud.splitlines()) > 4  # the table, without -q
    code, out, err = _cli(["identify", campaign, "--model", "bouc-wen", "--out", tmp_path / "b",
                           "--jobs", "1", "--quiet"])
    assert code == 0 and out.splitlines() == [
        f"wrote {tmp_path / 'b' / 'identification.json'} and {tmp_path / 'b' / 'predictions.h5'}"]
    assert all(ln.startswith("warning: ") for ln in err.splitlines()), err
    code, out, _ = _cli(["identify", campaign, "--model", "bouc-wen,duhem", "--out",
                         tmp_path / "laws", "--jobs", "1", "-q"])
    assert code == 0 and len(out.splitlines()) == 1 and out.startswith("wrote "), out


def test_quiet_diagnose_prints_its_verdict_and_outputs_only(campaign, tmp_path):
    args = ["diagnose", campaign, "--model", "bouc-wen", "--only", "viscous-friction",
            "--laws", "none", "--jobs", "1"]
    code, loud, _ = _cli([*args, "--out", tmp_path / "a"])
    assert code == 0 and "Ladder" in loud
    code, out, _ = _cli([*args, "--out", tmp_path / "b", "--quiet"])
    assert code == 0 and "Ladder" not in out and "ranking" not in out.lower()
    assert out.rstrip().splitlines()[-1].startswith("wrote ")
    assert len(out.splitlines()) < len(loud.splitlines()) // 2


# ------------------------------------------------------------------ the report's title page
def _title_text(pdf: Path) -> str:
    import pypdfium2 as pdfium

    return " ".join(pdfium.PdfDocument(str(pdf))[0].get_textpage().get_text_range().split())


def _title_page(directory: Path, out: Path) -> Path:
    """The title page of ``pmalab report DIRECTORY`` alone, as a PDF: the report's own plan
    (:func:`pmalab.reports.build.report_plan`) with its footer, its first page written as
    :func:`pmalab.reports.build.build_report` writes every page (the rest of the report is
    drawn in test_reports_build)."""
    from pmalab.reports.build import report_plan
    from pmalab.reports.pdf import write_pdf

    plan = report_plan([str(directory)])
    assert plan.pages[0].slug == "title", [p.slug for p in plan.pages]
    return write_pdf(out, plan.pages[:1], title=plan.title, footer=plan.footer)


def test_title_page_lists_each_run_once_under_its_role(tmp_path):
    diag = write_diagnosis_dir(tmp_path / "diag")  # held-out runs for base AND final model
    text = _title_text(_title_page(diag, tmp_path / "d.pdf"))
    assert "ident.h5: held out (2): p3102, p4762" in text, text
    # the diagnosis's own split names the identification runs too
    import json

    doc = json.loads((diag / "diagnosis.json").read_text())
    doc["settings"] = {**(doc.get("settings") or {}),
                       "identification_runs": ["ident.h5:p3102-a", "ident.h5:p4762-a"],
                       "held_out": ["ident.h5:p3102", "ident.h5:p4762"]}
    (diag / "diagnosis.json").write_text(json.dumps(doc))
    text = _title_text(_title_page(diag, tmp_path / "d2.pdf"))
    assert ("ident.h5: identification (2): p3102-a, p4762-a; held out (2): p3102, p4762"
            in text), text


def test_title_page_names_the_halves_of_a_split_record(tmp_path):
    from pmalab.reports.figures_text import runs_by_role

    inp = {"file": "k.h5", "runs": ["K_1bar-a", "K_3bar-a", "K_1bar-b", "K_3bar-b"],
           "roles": {"K_1bar-a": "identification", "K_3bar-a": "identification",
                     "K_1bar-b": "validation", "K_3bar-b": "validation"}}
    assert runs_by_role(inp) == ("identification (2): K_1bar-a, K_3bar-a; "
                                 "held out (2): K_1bar-b, K_3bar-b")
    ident = write_identification_dir(tmp_path / "id")
    text = _title_text(_title_page(ident, tmp_path / "i.pdf"))
    assert ("ident.h5: identification (3): p3102, p4762, p6000 val.h5: held out (2): p0498, "
            "p0304") in text, text


# ------------------------------------------------------------------ the README's example
@pytest.mark.slow
@pytest.mark.timeout(900)  # about a minute on an idle machine; a loaded one is slower
def test_readme_python_example_runs_alone_in_an_empty_directory(tmp_path):
    readme = (ROOT / "README.md").read_text()
    (code,) = re.findall(r"```python\n(.*?)```", readme, flags=re.S)
    env = {**os.environ, "MPLBACKEND": "Agg"}
    p = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, capture_output=True,
                       text=True, env=env, timeout=600)
    assert p.returncode == 0, p.stderr[-3000:]
    assert "viscous-friction" in p.stdout
    assert (tmp_path / "campaign.h5").is_file()


def test_the_final_model_is_named_with_the_law_the_ladder_ended_on():
    """A ladder that changes the law: the report's before/after page names the final model
    by the law in force at its last step, not the base law."""
    from pmalab.reports.build import _final_model_name

    ladder = [{"step": 0, "added": None, "law": "bouc-wen", "effects": []},
              {"step": 1, "added": "pressure-variation", "law": "bouc-wen",
               "effects": ["pressure-variation"]},
              {"step": 2, "added": None, "law": "maxwell-slip", "effects": ["pressure-variation"]},
              {"step": 3, "added": "sensor-delay", "law": "maxwell-slip",
               "effects": ["pressure-variation", "sensor-delay"]}]
    diag = {"model": "bouc-wen", "ladder": ladder}
    assert _final_model_name(diag) == "maxwell-slip + pressure-variation, sensor-delay"
    assert _final_model_name({**diag, "ladder": ladder[:3]}) == "maxwell-slip + pressure-variation"
    switched = [ladder[0], {"step": 1, "added": None, "law": "duhem", "effects": []}]
    assert _final_model_name({**diag, "ladder": switched}) == "duhem"
    old = [{"step": 0}, {"step": 1, "added": "viscous-friction"}]  # files without law/effects
    assert _final_model_name({**diag, "ladder": old}) == "bouc-wen + viscous-friction"
    assert _final_model_name({**diag, "ladder": ladder[:1]}) is None
