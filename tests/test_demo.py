"""`pmalab demo`: the whole chain on the simulated rig, end to end."""

from __future__ import annotations

import json

import pytest

from pmalab.cli import main


@pytest.mark.slow
@pytest.mark.timeout(600)  # the whole chain, 23 report pages included, on a loaded machine
def test_demo_finds_the_hidden_effect_and_writes_the_report(tmp_path, capsys):
    out = tmp_path / "demo"
    assert main(["demo", "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "diagnosis: found it\n" in text  # at once: no experiment round needed
    diag = json.loads((out / "diagnose" / "diagnosis.json").read_text())
    assert diag["ranking"][0]["effect"] == "asymmetric-hysteresis"
    assert diag["ranking"][0]["significant"] is True
    ladder = [s["nrmse"] for s in diag["ladder"]]
    assert ladder[-1] < 0.5 * ladder[0]  # the error falls by more than half
    # one error-fall figure: the summary prints the sentence the report's pages draw
    from pmalab.identify.headline import error_fall

    fall = error_fall(*(json.loads((out / d / "identification.json").read_text())
                        for d in ("identify", "identify-improved")))
    assert fall.sentence() in text and fall.fall_percent > 50.0
    pdf = out / "report.pdf"
    assert pdf.stat().st_size > 50_000 and pdf.read_bytes()[:5] == b"%PDF-"
    # the hidden effect's name must not leak into the files a user sees
    assert "asymmetric" not in (out / "rig" / "rig.toml").read_text()
    # never overwrite without --force
    assert main(["demo", "--out", str(out)]) != 0


def test_force_never_deletes_a_directory_of_other_work(tmp_path, capsys):
    """`demo --out DIR --force` replaces a demo's output; a directory holding anything else
    (a typo'd --out pointing at a results folder) is refused and left as it was."""
    out = tmp_path / "results"
    out.mkdir()
    (out / "thesis.tex").write_text("months of work\n")
    (out / "report.pdf").write_bytes(b"%PDF-")  # a demo name among them does not matter
    assert main(["demo", "--out", str(out), "--force"]) != 0
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "holds files the demo did not write (thesis.tex)" in err
    assert (out / "thesis.tex").read_text() == "months of work\n"


def test_verdict_names_active_rounds_only_when_diagnosis_ran_them():
    from pmalab.demo import _verdict

    ladder_rounds = {"rounds": [{"step": 1, "ambiguous": []}], "ambiguous": []}
    assert _verdict("inertia", ["inertia"], ladder_rounds) == "found it"
    active = {"rounds": [{"round": 1, "rig_time_s": 58.4}], "ambiguous": [],
              "settings": {"active": {"stop_reason": "unambiguous"}}}
    v = _verdict("viscous-friction", ["viscous-friction"], active)
    assert v.startswith("found it, after 1 experiment round(s)") and "(58 s of rig time)" in v
    assert _verdict("viscous-friction", ["sensor-delay"], {"ambiguous": []}).startswith(
        "did NOT find it")
