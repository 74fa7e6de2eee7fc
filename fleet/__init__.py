"""d1-fleet: fleet software for Unitree D1-550 arms (see the README)."""
