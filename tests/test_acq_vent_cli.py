"""`pmalab run` states a vent that was not confirmed even when the runs completed or the
protocol was refused (exit 4, one line naming the regulator and the operator's action)."""

from __future__ import annotations

from test_acq_fakes import make_fake_rig
from test_acq_rate_stats import PROTO

import pmalab.acquisition.cli as acq_cli
from pmalab.cli import main
from pmalab.rig.base import Limits, VentResult


def _run_cli(tmp_path, rig, monkeypatch, *extra):
    proto = tmp_path / "short.toml"
    proto.write_text(PROTO)
    monkeypatch.setattr(acq_cli, "load_rig_spec", lambda *a, **k: rig)
    return main(["run", "--rig", "fake", "--protocol", str(proto), "--out",
                 str(tmp_path / "v.h5"), "--quiet", *extra])


def test_a_completed_run_whose_final_vent_fails_exits_4_and_says_so(tmp_path, capsys,
                                                                    monkeypatch):
    rig = make_fake_rig()
    rig.muscle_supply.vent = lambda: VentResult.failed("no acknowledgement")
    assert _run_cli(tmp_path, rig, monkeypatch) == 4
    cap = capsys.readouterr()
    assert "v.h5: 2 runs, " in cap.out  # the data are kept and reported (--quiet: one line)
    err = cap.err.strip().splitlines()
    assert len(err) == 1 and err[0].endswith(
        "v.h5: all 2 runs recorded, but cylinder regulator vented (confirmed: fake regulator "
        "at 0 MPa); muscle regulator vent FAILED (no acknowledgement): close the muscle's "
        "supply valve and exhaust the muscle by hand")


def test_a_refusal_with_a_failed_vent_states_the_vent(tmp_path, capsys, monkeypatch):

    rig = make_fake_rig(limits=Limits(max_muscle_pressure_MPa=0.2))  # the protocol wants 0.3
    rig.cylinder_regulator.vent = lambda: VentResult.failed("link down")
    assert _run_cli(tmp_path, rig, monkeypatch) == 4
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "refused: field 'muscle_pressure_MPa' = 0.3 MPa" in err
    assert "cylinder regulator vent FAILED (link down): close the cylinder's supply" in err
    assert not (tmp_path / "v.h5").exists()
