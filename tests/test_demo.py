"""`pmalab demo`: refusals and the verdict's wording.

The whole chain end to end (it finds the hidden effect, the error falls, the report is
written, nothing is overwritten without --force) is checked on the installed wheel's demo
in ``test_wheel.py``: the suite runs the demo once."""

from __future__ import annotations

from pmalab.cli import main


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
