"""Every number a user types is checked where it is read: one line naming the option or
field, exit 2, nothing written (seeds, --fix values, --model lists, rig and protocol files)."""

from __future__ import annotations

import contextlib
import io

import pytest
from identify_synth import make_run

from pmalab.cli import main as pmalab_main
from pmalab.paths import RIGS_DIR
from pmalab.runfile import write_runs


def _cli(args) -> tuple[int, str]:
    err = io.StringIO()
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(err):
        code = pmalab_main([str(a) for a in args])
    return code, err.getvalue()


def _one_line(code: int, err: str, *needles: str) -> None:
    assert code == 2 and err.count("\n") == 1 and "Traceback" not in err, err
    for n in needles:
        assert n in err, err


PROTO = ('[[run]]\nname = "a"\nmuscle_pressure_MPa = {p}\nwaveform = "sine"\n'
         'frequency_Hz = 0.5\nmagnitude_MPa = 0.3\ncycles = {c}\n')


@pytest.mark.parametrize("seed", ["99999999999999999999999999", "-1", "1.5"])
def test_seeds(tmp_path, seed):
    (tmp_path / "p.toml").write_text(PROTO.format(p=0.4, c=1))
    code, err = _cli(["run", "--rig", "sim", "--protocol", tmp_path / "p.toml", "--out",
                      tmp_path / "o.h5", "--seed", seed])
    _one_line(code, err, "--seed")
    assert not (tmp_path / "o.h5").exists()


@pytest.fixture(scope="module")
def campaign(tmp_path_factory):
    d = tmp_path_factory.mktemp("c")
    run, _ = make_run("bouc-wen", 0.4, n=3000, f=0.5)
    return write_runs(d / "c.h5", [run])


@pytest.mark.parametrize(("fix", "needle"), [
    ("k=1e300", "outside the range of bouc-wen's 'k'"),
    ("n=nan", "finite"), ("n=inf", "finite"), ("n=-3", "outside the range of bouc-wen's 'n'"),
])
def test_fix_values(tmp_path, campaign, fix, needle):
    code, err = _cli(["identify", campaign, "--model", "bouc-wen", "--fix", fix,
                      "--out", tmp_path / "id"])
    _one_line(code, err, "--fix", needle)
    assert not (tmp_path / "id").exists()


@pytest.mark.parametrize("model", [",,", "bouc-wen,,duhem"])
def test_model_lists(tmp_path, campaign, model):
    code, err = _cli(["identify", campaign, "--model", model, "--out", tmp_path / "id"])
    _one_line(code, err, "--model")
    assert not (tmp_path / "id").exists()


@pytest.mark.parametrize(("edit", "needle"), [
    (("sample_rate_Hz = 500.0", "sample_rate_Hz = 1e9"), "sample_rate_Hz"),
    (("max_pressure_MPa = 0.9", "max_pressure_MPa = 90"), "max_pressure_MPa"),
])
def test_rig_file_values(tmp_path, edit, needle):
    rig = tmp_path / "rig.toml"
    rig.write_text((RIGS_DIR / "generic-modbus.toml").read_text().replace(*edit, 1))
    (tmp_path / "p.toml").write_text(PROTO.format(p=0.4, c=1))
    code, err = _cli(["run", "--rig", rig, "--protocol", tmp_path / "p.toml", "--out",
                      tmp_path / "o.h5"])
    _one_line(code, err, needle)


def test_rig_limits_beyond_physics(tmp_path):
    text = (RIGS_DIR / "sim.toml").read_text().replace(
        "max_muscle_pressure_MPa = 0.6", "max_muscle_pressure_MPa = 90").replace(
        '"../truth/default.toml"', f'"{RIGS_DIR.parent / "truth" / "default.toml"}"')
    (tmp_path / "rig.toml").write_text(text)
    (tmp_path / "p.toml").write_text(PROTO.format(p=0.4, c=1))
    code, err = _cli(["run", "--rig", tmp_path / "rig.toml", "--protocol", tmp_path / "p.toml",
                      "--out", tmp_path / "o.h5"])
    _one_line(code, err, "limits.max_muscle_pressure_MPa = 90")


@pytest.mark.parametrize(("p", "c", "needle"), [(90, 1, "muscle_pressure_MPa"),
                                                (0.4, "inf", "cycles")])
def test_protocol_values(tmp_path, p, c, needle):
    (tmp_path / "p.toml").write_text(PROTO.format(p=p, c=c))
    code, err = _cli(["run", "--rig", "sim", "--protocol", tmp_path / "p.toml", "--out",
                      tmp_path / "o.h5"])
    _one_line(code, err, needle)
