"""The viewer in a real headless Chromium (one xdist group: one browser at a time)."""
