"""A candidate whose identification raises — or whose own-fall check (the identified model
predicted without the effect) raises — is that candidate failing: one line naming it and
the reason in the summary and in diagnosis.json, never claimed, and the diagnosis goes on.
The base model's identification raising is one clear error line (nothing to diagnose
against)."""

from __future__ import annotations

import contextlib
import io
import json
from pathlib import Path
from types import SimpleNamespace

import pytest

from pmalab.cli import main as pmalab_main
from pmalab.identify.diagnosis import ladder
from pmalab.identify.diagnosis.ranking import Candidate, Scored, judge, raised
from pmalab.paths import DATA_DIR

EFFECTS = '''
from pmalab.identify.effects.base import Effect
from pmalab.identify.params import Param


class BrokenForce(Effect):
    id = "broken-force"
    title = "a force term that cannot be computed"

    def params(self, sig, force_scale):
        return [Param("brk_f", 0.1, 0.0, force_scale, "N", doc="force")]

    def force(self, sig, h, theta):
        raise ValueError("no force model for this rig")


class BrokenRemoval(Effect):
    # viscous friction written so that its "absent" value (c = 0) cannot be evaluated
    id = "broken-removal"
    title = "viscous friction that divides by its coefficient"
    absent = {"brr_c": 0.0}

    def params(self, sig, force_scale):
        return [Param("brr_c", 1.0, 0.0, 100.0, "N s/mm", doc="damping")]

    def force(self, sig, h, theta):
        if theta["brr_c"] == 0.0:
            raise ZeroDivisionError("scale / brr_c")
        return -theta["brr_c"] * sig.v
'''


def _cli(*args: str) -> tuple[int, str, str]:
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = pmalab_main(list(args))
    return code, out.getvalue(), err.getvalue()


@pytest.fixture(scope="module")
def campaign(tmp_path_factory) -> Path:
    """The tutorial's campaign (hidden viscous friction), recorded once for the module."""
    out = tmp_path_factory.mktemp("campaign") / "campaign.h5"
    code, _, err = _cli(
        "run", "--rig", str(DATA_DIR / "rigs" / "sim-viscous-friction.toml"),
        "--protocol", str(DATA_DIR / "protocols" / "diagnosis-test.toml"),
        "--out", str(out), "--quiet",
    )  # fmt: skip
    assert code == 0, err
    return out


def test_a_candidate_that_raises_is_reported_failed_and_the_diagnosis_goes_on(
    campaign, tmp_path
):
    effects = tmp_path / "broken.py"
    effects.write_text(EFFECTS)
    code, out, err = _cli(
        "diagnose", str(campaign), "--model", "bouc-wen", "--effects", str(effects),
        "--only", "viscous-friction", "--only", "broken-force", "--only", "broken-removal",
        "--laws", "none", "--max-steps", "1", "--jobs", "2", "--out", str(tmp_path / "d"),
    )  # fmt: skip
    assert code == 0, err
    doc = json.loads((tmp_path / "d" / "diagnosis.json").read_text())
    rows = {r["effect"]: r for r in doc["ranking"]}
    # the diagnosis went on: viscous friction (the campaign's hidden effect) is still found
    assert doc["ladder"][1]["added"] == "viscous-friction" and rows["viscous-friction"]["significant"]
    fit = rows["broken-force"]
    assert fit["status"] == "failed" and not fit["significant"] and not fit["significant_alone"]
    assert fit["reason"].startswith("the identification raised ValueError: no force model")
    assert f"({effects}, line 14)" in fit["reason"]  # where: the user's file and line
    assert fit["nrmse_after"] is None and fit["fall_percent"] is None
    removal = rows["broken-removal"]
    # its fit is as good as viscous friction's, but the fall cannot be credited: not claimed
    assert removal["status"] == "failed" and not removal["significant"]
    assert "the check that the fall is the effect's own" in removal["reason"]
    assert "raised ZeroDivisionError: scale / brr_c" in removal["reason"]
    assert removal["fall_percent"] is None and removal["gain_carried_x_floor"] is None
    # said once each, in the summary (printed) and in diagnosis.json, and failed last
    for text in (doc["summary"], out):
        assert text.count(f"broken-force: {fit['reason']}") == 1
        assert text.count(f"broken-removal: {removal['reason']}") == 1
    assert doc["ranking"][0]["effect"] == "viscous-friction"
    assert "fit failed" in out and "Traceback" not in err


def test_raised_names_the_innermost_frame_outside_the_libraries():
    import numpy as np

    def user_code():
        return np.linalg.inv(np.zeros((2, 2)))  # raises inside NumPy

    try:
        user_code()
    except Exception as exc:
        text = raised(exc)
    assert text.startswith("LinAlgError: Singular matrix (")
    assert text.endswith(f"{__file__}, line {user_code.__code__.co_firstlineno + 1})")
    assert raised(RuntimeError("two\nlines")) == "RuntimeError: two lines"


def test_a_raised_identification_is_failed_with_no_numbers_after_it():
    base = Scored(effects=(), nrmse=[0.10, 0.11])
    ok = Scored(effects=("viscous-friction",), nrmse=[0.05, 0.06])
    bad = Scored(effects=("inertia",), nrmse=[float("nan")] * 2, error="ValueError: x")
    cands, _ = judge([Candidate("inertia", base, bad, floors=[0.004] * 2),
                      Candidate("viscous-friction", base, ok, floors=[0.004] * 2)])
    assert [c.effect for c in cands] == ["viscous-friction", "inertia"]
    j = cands[1].as_json()
    assert j["status"] == "failed" and j["reason"] == "the identification raised ValueError: x"
    assert j["nrmse_after"] is None and j["per_run_after"] is None and not j["significant"]
    json.dumps(j, allow_nan=False)  # diagnosis.json is written without NaN


def test_a_base_model_that_raises_is_one_error_line(monkeypatch):
    def score_all(
        train, held, specs, jobs=1, progress=False, desc="", scheduler=None, pool=None,
        base_fits=None,
    ):
        return [
            Scored(s.effects, [float("nan")] * 2, error="ValueError: singular (law.py, line 3)")
            if not s.effects
            else Scored(s.effects, [0.01, 0.01])
            for s in specs
        ]

    monkeypatch.setattr(ladder, "score_all", score_all)
    monkeypatch.setattr(ladder, "heldout_floor", lambda r: 0.004)
    with pytest.raises(ladder.LadderError) as info:
        ladder.run_ladder(
            [SimpleNamespace(frequency=0.25)],  # pyright: ignore[reportArgumentType]
            ["held-a", "held-b"],  # pyright: ignore[reportArgumentType]  (never read)
            "bouc-wen",
            ["viscous-friction"],
        )
    assert str(info.value) == (
        "the base bouc-wen model's identification raised ValueError: singular (law.py, "
        "line 3): nothing to diagnose against"
    )


def test_a_law_whose_identification_raises_is_one_table_row_not_a_traceback(
    campaign, tmp_path, monkeypatch
):
    from pmalab.identify.diagnosis import ranking

    real = ranking.fit_and_validate

    def fit_and_validate(train, spec, *args, **kwargs):
        if spec.law == "duhem":
            raise FloatingPointError("duhem's hysteresis integral overflowed")
        return real(train, spec, *args, **kwargs)

    monkeypatch.setattr(ranking, "fit_and_validate", fit_and_validate)
    code, out, err = _cli(
        "diagnose", str(campaign), "--model", "bouc-wen", "--only", "viscous-friction",
        "--laws", "duhem", "--max-steps", "1", "--jobs", "1", "--out", str(tmp_path / "d"),
    )  # fmt: skip
    assert code == 0, err
    (law,) = json.loads((tmp_path / "d" / "diagnosis.json").read_text())["laws"]
    assert law["status"] == "failed" and law["nrmse_after"] is None
    assert law["reason"].startswith("the identification raised FloatingPointError: duhem's")
    # the laws table: the law's row says it failed, with no error after it
    row = next(line for line in out.splitlines() if line.lstrip().startswith("duhem"))
    assert "fit failed" in row and "—" in row, row
    assert "Traceback" not in err


def test_raised_passes_generated_code_without_failing_itself():
    """A dataclass's generated ``__init__`` (file ``<string>``, pmalab's module globals)
    on the way to the error: named neither as a file nor relative to pmalab's tree (which
    raised ValueError inside the handler meant to report the candidate's failure)."""
    from pmalab.channels import Channel
    from pmalab.errors import ConfigError

    with pytest.raises(ConfigError) as info:
        Channel("x", "no-such-kind")
    assert raised(info.value) == (
        "ConfigError: channel 'x': unknown kind 'no-such-kind' (known: "
        + info.value.args[0].split("(known: ")[1]
        + " (pmalab/channels.py, line "
        + str(Channel.__post_init__.__code__.co_firstlineno + 2)
        + ")"
    )


def test_raised_names_installed_code_inside_the_standard_librarys_directory(monkeypatch):
    """A system Python keeps site-packages inside the standard library's directory
    (/usr/lib/python3.x/site-packages): pmalab installed there is still named."""
    import sysconfig
    from pathlib import Path

    import pmalab
    from pmalab.channels import Channel

    site = str(Path(pmalab.__file__).parent.parent)
    paths = {**sysconfig.get_paths(), "stdlib": str(Path(site).parent), "purelib": site}
    monkeypatch.setattr(sysconfig, "get_paths", lambda *a, **k: paths)
    try:
        Channel("x", "no-such-kind")
    except Exception as exc:
        text = raised(exc)
    assert text.endswith(
        f"(pmalab/channels.py, line {Channel.__post_init__.__code__.co_firstlineno + 2})"
    ), text
