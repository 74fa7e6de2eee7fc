"""Choreography: script files, a pure timeline, and the player that streams it.

User guide: docs/guide/scripting.md."""
