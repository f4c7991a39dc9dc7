"""Active identification: `pmalab diagnose CAMPAIGN --rig RIG --run-suggested`.

A single-frequency campaign (data/protocols/single-frequency.toml, 2 Hz) on the simulated rig
with a hidden 12 ms channel delay sized 2–4× the noise floor (data/truth/subtle/) leaves
sensor-delay and viscous-friction ambiguous — at one frequency both add a force ∝ ẋ.  The
loop must design an experiment that separates them, run it on the rig, append it and end
with the right effect first and not ambiguous.  The 10-seed rate is `make bench`'s
(bench/bench_active.py); here one seed that starts ambiguous, clean data, a declined
experiment and an aborted round.
"""

from __future__ import annotations

import contextlib
import copy
import hashlib
import io
import json
import shutil
from pathlib import Path

import pytest

from pmalab.active import diagnose as active_diagnose
from pmalab.active.design import candidate_experiments, experiment_toml, synth_position
from pmalab.active.loop import RoundAborted
from pmalab.cli import main as pmalab_main
from pmalab.errors import PmalabError
from pmalab.paths import PROTOCOLS_DIR, TRUTH_DIR
from pmalab.runfile import read_runs

PROTOCOL = PROTOCOLS_DIR / "single-frequency.toml"
SUBTLE = TRUTH_DIR / "subtle"
SEED = 3  # a sensor seed whose single-frequency campaign starts ambiguous (checked below)



@pytest.fixture(autouse=True)
def _the_commands_default_workers(monkeypatch):
    """The active loop with the command's default workers (the suite's PMALAB_JOBS=1 is
    dropped here): fitted in the pytest worker's own process its rounds cost ~40 % more
    CPU than with two workers (7 s of it system time), though from the shell ``--jobs 1``
    is the cheaper; measured, not yet understood."""
    monkeypatch.delenv("PMALAB_JOBS", raising=False)


def _rig(work: Path, truth: str, seed: int = SEED, limits: str = "") -> Path:
    rig = work / f"rig-{truth}-{seed}{'-lim' if limits else ''}.toml"
    rig.write_text(f'[rig]\nkind = "sim"\ntruth = "{(SUBTLE / truth).with_suffix(".toml")}"\n'
                   f"seed = {seed}\n{limits}")
    return rig


def _run(argv: list[str]) -> tuple[int, str, str]:
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        rc = pmalab_main(argv)
    return rc, out.getvalue(), err.getvalue()


@pytest.fixture(scope="module")
def delay_campaign(tmp_path_factory) -> tuple[Path, Path]:
    work = tmp_path_factory.mktemp("active-delay")
    rig = _rig(work, "sensor-delay")
    camp = work / "campaign.h5"
    rc, _, err = _run(["run", "--rig", str(rig), "--protocol", str(PROTOCOL), "--out", str(camp),
                       "-q"])
    assert rc == 0, err
    return rig, camp


def _key(value):
    """A hashable key of a call's arguments: runs by their samples and attrs, functions by
    name, containers by their items."""
    import numpy as np

    from pmalab.runfile import Run

    if isinstance(value, Run):
        h = hashlib.sha256(repr(sorted(value.attrs.items())).encode())
        for ch in ("time", "position", "force", "muscle_pressure", "cylinder_pressure"):
            a = getattr(value, ch)
            h.update(b"-" if a is None else np.ascontiguousarray(a).tobytes())
        return ("run", value.name, h.hexdigest())
    if isinstance(value, dict):
        return tuple(sorted((k, _key(v)) for k, v in value.items()))
    if isinstance(value, list | tuple):
        return tuple(_key(v) for v in value)
    if callable(value):
        return ("fn", getattr(value, "__qualname__", repr(value)))
    return value


@pytest.fixture(scope="module", autouse=True)
def _computed_once():
    """The delay campaign's initial diagnosis and its first round's experiment design are
    one computation in the three tests that start from them (the run on the rig, the
    declined experiment, the trip): each is computed once here, keyed on the runs' samples
    and every argument, and every test makes all its assertions on it (a copy).  Any other
    call (a later round's, another campaign's) is computed."""
    from pmalab.active import loop

    memo: dict = {}

    def once(fn):
        def call(*args, **kwargs):
            key = (fn.__name__, _key(args), _key(kwargs))
            if key not in memo:
                memo[key] = fn(*args, **kwargs)
            return copy.deepcopy(memo[key])

        return call

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(loop, "diagnose", once(loop.diagnose))
        mp.setattr(loop, "design", once(loop.design))
        yield


def _sha(p: Path) -> str:
    return hashlib.sha256(p.read_bytes()).hexdigest()


@pytest.mark.slow
def test_run_suggested_resolves_delay_vs_viscous_on_the_rig(delay_campaign, tmp_path):
    rig, src = delay_campaign
    camp = tmp_path / "campaign.h5"
    shutil.copy2(src, camp)
    n0 = len(read_runs(camp))
    rc, out, err = _run(["diagnose", str(camp), "--model", "bouc-wen", "--rig", str(rig),
                         "--run-suggested", "--yes", "--budget", "300", "--out",
                         str(tmp_path / "d")])
    assert rc == 0, err
    d = json.loads((tmp_path / "d" / "diagnosis.json").read_text())
    active = d["settings"]["active"]
    # it started ambiguous between the two look-alikes (else this seed tests nothing)
    assert sorted(active["initial_verdict"]["ambiguous"]) == ["sensor-delay", "viscous-friction"]
    assert 1 <= len(d["rounds"]) <= 2
    assert d["ranking"][0]["effect"] == "sensor-delay" and d["ranking"][0]["significant"]
    assert d["ambiguous"] == []
    assert active["stop_reason"] == "unambiguous"
    assert active["rig_time_s"] <= 300.0
    for i, r in enumerate(d["rounds"], 1):
        assert r["round"] == i
        assert r["expected_separation"]["min_x_floor"] >= 1.0
        assert r["experiment"]["frequency_Hz"] > 0 and r["experiment"]["runs"]
        assert r["verdict"]["first"] in ("sensor-delay", "viscous-friction")
        # the protocol shown is the protocol recorded: its runs are in the campaign now
        assert set(r["recorded_runs"]) == {x["name"] for x in r["experiment"]["runs"]}
        assert Path(r["file"]).is_file()
    runs = read_runs(camp)
    added = sum(len(r["recorded_runs"]) for r in d["rounds"])
    assert len(runs) == n0 + added
    assert "Stopped: the verdict is unambiguous" in out
    # a diagnosis with active rounds is read by the typed reader and drawn by the report
    from pmalab.identify.schema import read_diagnosis
    from pmalab.reports import load_report_dir, plan_pages
    from pmalab.reports.build import draw_page
    from pmalab.reports.layout import page_problems

    assert read_diagnosis(tmp_path / "d" / "diagnosis.json")["rounds"] == d["rounds"]
    data = load_report_dir(tmp_path / "d")
    pages = plan_pages(data)
    page = next(p for p in pages if p.title.startswith("Active identification"))
    assert page_problems(draw_page(page, data, 1, len(pages))) == []


def test_declined_experiment_runs_nothing_and_leaves_the_campaign(delay_campaign, tmp_path):
    rig, src = delay_campaign
    camp = tmp_path / "campaign.h5"
    shutil.copy2(src, camp)
    before = _sha(camp)
    asked = []

    def no(exp, toml):
        asked.append((exp, toml))
        return False

    res = active_diagnose(camp, rig=str(rig), confirm=no, jobs=2)  # the CLI's default jobs
    assert len(asked) == 1  # asked once, with the protocol it would run
    exp, toml = asked[0]
    assert "[[run]]" in toml and f"frequency_Hz = {exp.frequency_Hz!r}" in toml
    assert res.stop_reason == "declined" and res.rounds == []
    assert _sha(camp) == before
    assert not list(tmp_path.glob("campaign-round*.h5"))


def test_a_trip_mid_round_keeps_the_campaign_and_the_samples(delay_campaign, tmp_path):
    _, src = delay_campaign
    camp = tmp_path / "campaign.h5"
    shutil.copy2(src, camp)
    before = _sha(camp)
    # the same rig with a force limit the suggested runs exceed: the runner trips mid-run
    low = _rig(tmp_path, "sensor-delay", limits="[limits]\nmax_force_N = 450.0\n")
    rc, _, err = _run(["diagnose", str(camp), "--model", "bouc-wen", "--rig", str(low),
                       "--run-suggested", "--yes", "--out", str(tmp_path / "d")])
    assert rc == 4, err
    line = err.strip().splitlines()[-1]
    assert "unchanged" in line and "round1" in line and "vented" in line
    assert _sha(camp) == before
    kept = read_runs(tmp_path / "campaign-round1.h5")  # aborted runs included
    assert any(r.state == "aborted" and len(r) > 0 for r in kept)
    # the diagnosis of what was recorded before the round is written
    d = json.loads((tmp_path / "d" / "diagnosis.json").read_text())
    assert d["settings"]["active"]["stop_reason"] == "aborted"


def test_clean_single_frequency_data_runs_at_most_one_round_and_claims_nothing(tmp_path):
    rig = _rig(tmp_path, "clean", seed=11)
    camp = tmp_path / "campaign.h5"
    assert _run(["run", "--rig", str(rig), "--protocol", str(PROTOCOL), "--out", str(camp),
                 "-q"])[0] == 0
    res = active_diagnose(camp, rig=str(rig), confirm=None, budget_s=120)
    assert len(res.rounds) <= 1
    assert not any(r["significant"] for r in res.diagnosis.ranking)


def test_bad_use_is_one_line(delay_campaign, tmp_path):
    rig, camp = delay_campaign
    for argv, needle in (
        (["--run-suggested"], "needs --rig"),
        (["--rig", str(rig)], "only used with --run-suggested"),
        (["--rig", str(rig), "--run-suggested", "--budget", "-5"], "--budget"),
        # a plain diagnosis's option the loop cannot honour is refused, never ignored
        (["--rig", str(rig), "--run-suggested", "--pressure", "measured"],
         "--pressure measured cannot be used with it"),
        (["--rig", str(rig), "--run-suggested", "--include-aborted"],
         "--include-aborted cannot be used with it"),
        (["--rig", str(rig), "--run-suggested", "--max-steps", "-1"], "--max-steps -1"),
    ):
        rc, _, err = _run(["diagnose", str(camp), "--model", "bouc-wen", "--out",
                           str(tmp_path / "o"), *argv])
        assert rc != 0 and needle in err and "Traceback" not in err
        assert len(err.strip().splitlines()) == 1


def test_design_pieces():
    import numpy as np

    t = np.arange(0, 2.0, 0.002)
    x = synth_position(t, "triangle", 1.0, 10.0, 5.0)
    assert abs(x.max() - 15.0) < 0.2 and abs(x.min() - 5.0) < 0.2  # rounded corners only
    s = synth_position(t, "sine", 1.0, 10.0, 5.0)
    assert abs(s[0] - 5.0) < 1e-9  # starts stretched (minimum contraction)
    from pmalab.active.design import Experiment

    e = Experiment("triangle", 4.0, 0.5, 6.0,
                   [{"name": "a", "muscle_pressure_MPa": 0.35, "frequency_Hz": 4.0,
                     "waveform": "triangle", "cycles": 6.0, "role": "validation"}])
    toml = experiment_toml(e, "p", "because")
    import tomllib

    doc = tomllib.loads(toml)
    assert doc["run"][0]["frequency_Hz"] == 4.0 and doc["protocol"]["name"] == "p"
    with pytest.raises(PmalabError):
        raise RoundAborted("x", None, Path("f"))  # type: ignore[arg-type]
    assert candidate_experiments([]) and all(len(c) == 3 for c in candidate_experiments([]))


def test_run_suggested_diagnoses_with_the_options_given(delay_campaign, tmp_path, monkeypatch):
    # --laws, --max-steps, --effects and --whole-run reach every diagnosis the loop makes
    # (they were silently dropped: the loop diagnosed with every law and three steps)
    import pmalab.active.loop as loop

    rig, camp = delay_campaign
    seen: list[dict] = []

    class Stop(Exception):
        pass

    def fake(runs, model, **kw):
        seen.append(kw)
        raise Stop

    monkeypatch.setattr(loop, "diagnose", fake)
    user = tmp_path / "my_effects.py"
    user.write_text("")
    with pytest.raises(Stop):
        pmalab_main(["diagnose", str(camp), "--model", "bouc-wen", "--rig", str(rig),
                     "--run-suggested", "--yes", "--laws", "none", "--max-steps", "1",
                     "--effects", str(user), "--whole-run", "--out", str(tmp_path / "o")])
    (kw,) = seen
    assert kw["laws"] == [] and kw["max_steps"] == 1 and kw["whole_run"] is True
    assert [str(f) for f in kw["effects_files"]] == [str(user)]


def test_the_experiment_is_designed_for_the_law_the_ladder_ended_with(delay_campaign,
                                                                      monkeypatch):
    # the ladder switched the law (bouc-wen -> maxwell-slip): the candidate models the round's
    # experiment is designed on are the final model's law plus each ambiguous effect, and
    # they are built with the user effect files the diagnosis was given
    from types import SimpleNamespace

    import pmalab.active.loop as loop

    _, camp = delay_campaign
    d = SimpleNamespace(ranking=[], settings={"held_out": []}, ladder=[], model="bouc-wen",
                        final_law="maxwell-slip", final_effects=["viscous-friction"],
                        ambiguous=["sensor-delay", "inertia"], verdict="unexplained",
                        noise_floor={"per_run": {}})
    seen: list = []

    def design(runs, law, base, ambiguous, floors, **kw):
        seen.append((law, list(base), kw.get("effects_files")))
        return None, [], []

    monkeypatch.setattr(loop, "diagnose", lambda runs, model, **kw: d)
    monkeypatch.setattr(loop, "design", design)
    res = loop.diagnose_active(camp, lambda *a: [], options={"effects_files": ["my.py"]},
                               log=lambda s: None)
    assert res.stop_reason == "no-experiment"
    assert seen == [("maxwell-slip", ["viscous-friction"], ["my.py"])]
    assert res.initial_verdict["final_model"] == "maxwell-slip+viscous-friction"
