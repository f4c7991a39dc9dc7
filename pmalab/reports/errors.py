"""The reports area's user error."""

from __future__ import annotations

from pathlib import Path

from pmalab.errors import OutputError, OutputExistsError, PmalabError
from pmalab.paths import check_output


class ReportError(PmalabError):
    """A result directory (identification.json, diagnosis.json, predictions.h5) is missing
    or malformed; the message names the file and the key/group at fault."""


def report_output(out: str | Path, force: bool) -> Path:
    """``out`` checked as a report's output: an existing file without ``force`` is
    :class:`~pmalab.errors.OutputExistsError` (the CLI's ``--force`` hint); any other
    refusal (a parent that is a file, say) is a :class:`ReportError`."""
    out = Path(out)
    try:
        check_output(out, force)
    except OutputExistsError:
        raise
    except OutputError as exc:
        raise ReportError(str(exc)) from None
    return out
