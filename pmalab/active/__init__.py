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

    ``rig``: ``"sim"`` or a rig TOML path (or a recorder callable, see
    :func:`~pmalab.active.loop.diagnose_active`); ``confirm(experiment, protocol_toml) ->
    bool``: a lab's own confirmation dialog (None: run without asking).  With
    ``run_suggested=False`` no experiment is run (one diagnosis, no rounds).
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
