"""Where the fleet's processes keep state across restarts on this host: ``$D1_FLEET_STATE_DIR``,
else ``$XDG_STATE_HOME/d1-fleet``, else ``~/.local/state/d1-fleet`` (the demo gives each run a
directory of its own). The agents keep their latched stops there (edge_agent/latches.py), the
viewer its token (fleet/web/token_store.py)."""

from __future__ import annotations

import os
from pathlib import Path

STATE_ENV = "D1_FLEET_STATE_DIR"


def default_state_dir() -> Path:
    """The state directory of this host's fleet processes."""
    given = os.environ.get(STATE_ENV)
    if given:
        return Path(given)
    base = os.environ.get("XDG_STATE_HOME") or str(Path.home() / ".local" / "state")
    return Path(base) / "d1-fleet"
