"""Active identification: the diagnosis runs the experiment it suggests, on the rig.

:func:`~pmalab.active.loop.diagnose_active` (and ``pmalab diagnose CAMPAIGN.h5 --rig RIG
--run-suggested``) designs the experiment that separates ambiguous candidate effects most
(:mod:`pmalab.active.design`), records it through the acquisition runner and diagnoses
again.  This package sits above both ``identify`` and ``acquisition``: identification
never touches the rig.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from pmalab.lazy import lazy_exports

if TYPE_CHECKING:
    from pathlib import Path

    from pmalab.active.loop import ActiveResult, Recorder

# imported on first use: `pmalab --help` registers this package's options without numpy
_getattr, _names = lazy_exports(
    __name__,
    {
        n: "pmalab.active.loop"
        for n in ("ActiveResult", "ActiveRound", "diagnose_active", "rig_recorder")
    },
)
__all__ = ["diagnose", *_names]


def __getattr__(name: str):
    return _getattr(name)


def diagnose(
    campaign,
    *,
    rig: str | Path | Recorder,
    run_suggested: bool = True,
    model: str = "bouc-wen",
    budget_s: float = 300.0,
    confirm=None,
    max_rounds: int = 3,
    seed: int | None = None,
    **kwargs,
) -> ActiveResult:
    """``pmalab diagnose CAMPAIGN --rig RIG --run-suggested`` from Python.

    Diagnose the campaign; while the ranking is ambiguous, record the experiment that tells
    the look-alikes apart on the rig, add it and diagnose again, within a rig-time budget.

    Parameters
    ----------
    campaign
        The campaign's run file (HDF5).
    rig
        ``"sim"``, a shipped rig's name or a rig TOML path, or a recorder callable (see
        :func:`~pmalab.active.loop.diagnose_active`).
    run_suggested
        Record the suggested experiments; ``False``: one diagnosis, no rounds.
    model
        The base law id.
    budget_s
        The rig time the suggested experiments may use in total, s.
    confirm
        ``confirm(experiment, protocol_toml) -> bool``: a lab's own confirmation before
        anything moves (``None``: run without asking).
    max_rounds
        The most experiments recorded.
    seed
        The simulated rig's sensor-noise seed (``None``: the rig file's).
    **kwargs
        The options of :func:`pmalab.identify.diagnosis.diagnose`.

    Returns
    -------
    ActiveResult
        The final diagnosis, the rounds run (each with its experiment, expected separation
        and verdict), the rig time used and why the loop stopped.
    """
    from pmalab.active.loop import diagnose_active, protocol_duration, rig_recorder

    record = rig if callable(rig) else rig_recorder(str(rig), seed=seed)
    return diagnose_active(
        campaign,
        record,
        model=model,
        budget_s=budget_s,
        confirm=confirm,
        max_rounds=max_rounds if run_suggested else 0,
        protocol_duration=protocol_duration,
        **kwargs,
    )
