"""The environment a user's shell gives a command the suite starts in a subprocess."""

from __future__ import annotations

import os

#: variables the suite sets for itself (``conftest.py``: ``PMALAB_JOBS=1``, so commands run
#: by pytest workers start no worker pools, and ``OPENBLAS_NUM_THREADS=1``) — never in what
#: a user's shell has
SUITE_ONLY = ("PMALAB_JOBS", "OPENBLAS_NUM_THREADS")


def shell_env(*drop: str) -> dict[str, str]:
    """``os.environ`` without the suite's own variables (:data:`SUITE_ONLY`) and the
    variables named in ``drop`` (e.g. ``PYTHONPATH``, so an installed package is what
    imports)."""
    gone = {*SUITE_ONLY, *drop}
    return {k: v for k, v in os.environ.items() if k not in gone}
