"""The documentation build's hook (``docs/hooks/show.py``), loaded as a module for the tests
that read what the build ran (each page's commands, the units it made and where)."""

from __future__ import annotations

import importlib.util
from pathlib import Path
from types import ModuleType

ROOT = Path(__file__).resolve().parents[1]


def show_hook() -> ModuleType:
    """A fresh module of ``docs/hooks/show.py`` (its ``RUN_PAGES``, ``BASH``, ``built()``,
    ``unit()`` …), the file the site build runs."""
    spec = importlib.util.spec_from_file_location("docs_show", ROOT / "docs" / "hooks" / "show.py")
    assert spec is not None and spec.loader is not None
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod
