"""A process for ``test_forkserver``: prints what it was started with, then exits as asked."""

import json
import os
import signal
import sys
import threading
import time

print(
    json.dumps(
        {
            "argv": sys.argv[1:],
            "cwd": os.getcwd(),
            "marker": os.environ.get("FORKSERVER_MARKER"),
            "stdin": sys.stdin.read(),
            "threads": threading.active_count(),
            "main": __name__,
            "nice": os.getpriority(os.PRIO_PROCESS, 0),
        }
    )
)
print("to stderr", file=sys.stderr)
if sys.argv[1] == "wait":
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(7))
    deadline = time.monotonic() + 30.0
    while time.monotonic() < deadline:
        time.sleep(0.05)
sys.exit(int(sys.argv[2]))
