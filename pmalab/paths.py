"""Where shipped data lives (protocols, rig files, truth files)."""

from __future__ import annotations

from pathlib import Path

from pmalab.errors import OutputExistsError

REPO_ROOT = Path(__file__).resolve().parent.parent
DATA_DIR = REPO_ROOT / "data"
PROTOCOLS_DIR = DATA_DIR / "protocols"
RIGS_DIR = DATA_DIR / "rigs"
TRUTH_DIR = DATA_DIR / "truth"


def check_output(path: str | Path, force: bool) -> Path:
    """Refuse to overwrite ``path`` unless ``force``; return it as a Path."""
    p = Path(path)
    if p.exists() and not force:
        raise OutputExistsError(f"{p}: already exists (use --force to overwrite)")
    return p
