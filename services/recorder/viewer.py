"""Where the Rerun viewer is, without importing rerun (half a second): the report of every run
names it."""

from __future__ import annotations

import shutil
import sys
from pathlib import Path


def viewer_command() -> list[str] | None:
    """The Rerun viewer: the `rerun` beside this Python (a venv's), else one on PATH."""
    beside = Path(sys.executable).with_name("rerun")
    found = str(beside) if beside.exists() else shutil.which("rerun")
    return [found] if found else None
