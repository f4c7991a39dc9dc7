"""The reports area's user error."""

from __future__ import annotations

from pmalab.errors import PmalabError


class ReportError(PmalabError):
    """A result directory (identification.json, diagnosis.json, predictions.h5) is missing
    or malformed; the message names the file and the key/group at fault."""
