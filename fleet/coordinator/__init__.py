"""The fleet coordinator: fleet state, multi-arm commanding, stop bookkeeping, heartbeat."""
