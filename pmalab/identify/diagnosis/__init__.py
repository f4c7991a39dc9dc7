"""Diagnosis: rank missing effects by what ``identify --add`` gives, climb the ladder, say
what is left against the measurement-noise floor.

Modules: :mod:`.heldout` (which runs are held out), :mod:`.ranking` (scoring through the
one identification), :mod:`.ladder`, :mod:`.diagnostics` (residual maps), :mod:`.diagnose`
(the orchestration, JSON and predictions output).
"""

from __future__ import annotations

from pmalab.identify.diagnosis.diagnose import (
    DiagnoseError,
    Diagnosis,
    diagnose,
    write_outputs,
)
from pmalab.identify.predictions import PREDICTIONS_FORMAT

__all__ = ["PREDICTIONS_FORMAT", "DiagnoseError", "Diagnosis", "diagnose", "write_outputs"]
