"""Choreography: script files, a pure timeline, and the player that streams it (README)."""
