"""Where bioscara keeps its files on the host."""

from __future__ import annotations

import os
from pathlib import Path


def default_state_dir() -> Path:
    """$XDG_STATE_HOME/bioscara, or ~/.local/state/bioscara when it is unset or not absolute."""
    xdg = os.environ.get("XDG_STATE_HOME", "")
    base = Path(xdg) if os.path.isabs(xdg) else Path.home() / ".local" / "state"
    return base / "bioscara"
