"""Process plumbing shared by every entry point: logging (text or JSON lines, stderr or a file),
signals, the inventory options."""

from __future__ import annotations

import argparse
import contextlib
import faulthandler
import json
import logging
import logging.handlers
import os
import signal
import sys
import threading
from datetime import datetime, timezone
from types import FrameType, TracebackType

from fleet.inventory import DEFAULT_INVENTORY, Inventory, InventoryError, load_inventory

LOG_FORMATS = ("text", "json")
TEXT_FORMAT = (
    "%(asctime)s %(levelname)s %(role)s[%(process)d] %(name)s [%(threadName)s] %(message)s"
)


class LogFileError(Exception):
    """``--log-file`` names a file this process cannot open for append (a usage error: exit 2)."""


class JsonLineFormatter(logging.Formatter):
    """One JSON object per line: ``time`` (ISO 8601, UTC, microseconds), ``level``, ``logger``,
    ``thread``, ``message``, ``role`` (router, sim, agent, ...), ``pid``, and ``exc`` (the
    traceback) when there is one. A message's own newlines are escaped, so a line is a record."""

    def format(self, record: logging.LogRecord) -> str:
        line: dict[str, object] = {
            "time": datetime.fromtimestamp(record.created, timezone.utc).isoformat(
                timespec="microseconds"
            ),
            "level": record.levelname,
            "logger": record.name,
            "thread": record.threadName,
            "message": record.getMessage(),
            "role": getattr(record, "role", ""),
            "pid": record.process,
        }
        if record.exc_info:
            line["exc"] = self.formatException(record.exc_info)
        if record.stack_info:
            line["stack"] = self.formatStack(record.stack_info)
        return json.dumps(line, ensure_ascii=False)


class _RoleFilter(logging.Filter):
    """Stamps every record that reaches our handler with the process's role."""

    def __init__(self, role: str) -> None:
        super().__init__()
        self.role = role

    def filter(self, record: logging.LogRecord) -> bool:
        record.role = self.role
        return True


_OUR_HANDLERS: list[logging.Handler] = []
"""The handler the last setup_logging installed (a list, so a later call can replace it)."""


class _StderrHandler(logging.StreamHandler):  # type: ignore[type-arg]
    """Writes to whatever ``sys.stderr`` is at each record (as logging's own last resort does),
    not the stream of the moment it was made: a command run in-process (the tests) must not
    leave a handler on a stream that is closed later ("I/O operation on closed file")."""

    def __init__(self) -> None:
        super().__init__(sys.stderr)

    @property  # type: ignore[override]
    def stream(self):  # type: ignore[no-untyped-def]
        return sys.stderr

    @stream.setter
    def stream(self, _value: object) -> None:
        pass


def setup_logging(
    level: str = "INFO", log_file: str | None = None, log_format: str = "text", role: str = "fleet"
) -> None:
    """The one logging set-up of every process of the fleet: text or JSON lines, to stderr
    (the journal, under systemd) or appended to ``log_file``. The file is a WatchedFileHandler:
    logrotate may move it away and the next record reopens the path, and several processes (the
    demo's children) may append to one file (O_APPEND; a record is one write). Raises
    LogFileError when the file cannot be opened. Calling it again replaces our handler only."""
    handler: logging.Handler
    if log_file is None:
        handler = _StderrHandler()
    else:
        try:
            handler = logging.handlers.WatchedFileHandler(log_file, mode="a", encoding="utf-8")
        except OSError as exc:
            raise LogFileError(
                f"--log-file {log_file}: cannot open it for append: {exc.strerror or exc}"
            ) from None
    formatter = JsonLineFormatter() if log_format == "json" else logging.Formatter(TEXT_FORMAT)
    handler.setFormatter(formatter)
    handler.addFilter(_RoleFilter(role))
    root = logging.getLogger()
    while _OUR_HANDLERS:  # ours only: pytest's capture (or anyone's) stays
        old = _OUR_HANDLERS.pop()
        root.removeHandler(old)
        old.close()
    root.addHandler(handler)
    _OUR_HANDLERS.append(handler)
    root.setLevel(getattr(logging, level.upper(), logging.INFO))
    if log_file is not None:
        _log_uncaught(logging.getLogger(role))


def _log_uncaught(log: logging.Logger) -> None:
    """A crash of the main thread lands in the log file too (threads log theirs: fleet.guard).
    Installed once per process; the interpreter's own hook still prints to stderr."""
    previous = sys.excepthook
    if getattr(previous, "_d1_fleet_logs", False):
        return

    def hook(kind: type[BaseException], exc: BaseException, tb: TracebackType | None) -> None:
        if not issubclass(kind, KeyboardInterrupt):
            log.critical("uncaught exception", exc_info=(kind, exc, tb))
        previous(kind, exc, tb)

    hook._d1_fleet_logs = True  # type: ignore[attr-defined]
    sys.excepthook = hook


def setup_logging_from_args(args: argparse.Namespace, role: str) -> None:
    """``setup_logging`` with ``--log-level``, ``--log-file`` and ``--log-format``."""
    setup_logging(
        getattr(args, "log_level", "INFO"),
        getattr(args, "log_file", None),
        getattr(args, "log_format", "text"),
        role,
    )


SHUTDOWN_BOUND_S = 8.0
"""A process still running this long after its first SIGINT/SIGTERM/SIGHUP prints every
thread's stack to stderr and exits (code 1): a shutdown stuck in a library call (a Zenoh
undeclare or close, a DDS delete, a join) must neither outlive its supervisor's patience (the
demo and the tests wait 10 s, then SIGKILL, which says nothing) nor leave no trace of where it
hung. Normal shutdowns take 0.1-3 s (``close_bounded`` caps a session's close at 2 s)."""


class _SignalRelay:
    """Sets a process's shutdown Event on a thread of its own, told by its signal handler
    through a pipe. A Python signal handler runs in the main thread between two bytecodes,
    and the main thread may be inside ``Event.wait`` holding the very lock ``Event.set`` takes:
    a handler that set the Event itself deadlocked (seen once in a suite run: a simulator's
    main thread in ``Condition.wait`` -> ``_release_save`` -> the handler -> ``Event.set`` ->
    the same lock, until the shutdown bound killed it). Logging takes locks too, so the
    signal's log line is written here as well. Writing to a pipe takes none."""

    def __init__(self) -> None:
        self._read, self._write = os.pipe()
        os.set_blocking(self._write, False)
        self.target: tuple[threading.Event, bool] | None = None
        """The Event to set and whether to log the signal (the newest ``shutdown_event``)."""
        threading.Thread(target=self._run, name="signals", daemon=True).start()

    def notify(self, signum: int) -> None:
        """From the signal handler: no lock, no allocation beyond the byte."""
        with contextlib.suppress(OSError):  # full: the relay has signals to act on already
            os.write(self._write, bytes([signum]))

    def _run(self) -> None:
        while True:
            signums = os.read(self._read, 64)
            if not signums:
                return
            target = self.target
            if target is None:
                continue
            stop, quiet = target
            if not quiet:
                for signum in signums:
                    name = signal.Signals(signum).name
                    logging.getLogger("fleet").info("received %s, shutting down", name)
            stop.set()


_relay: _SignalRelay | None = None


def shutdown_event(
    quiet: bool = False, bound_s: float | None = SHUTDOWN_BOUND_S
) -> threading.Event:
    """An Event set by SIGINT, SIGTERM or SIGHUP (its terminal closed): call from the main
    thread. A service logs the signal; ``quiet``: a command a user ends with Ctrl-C (``status
    --watch``, ``hz``, ``echo``, ``diag``) just ends, no log line. From the first signal the
    process has ``bound_s`` to exit (``SHUTDOWN_BOUND_S``; None: no bound, for a supervisor
    that bounds its children's shutdowns itself). The Event is set just after the handler
    returns, by the process's signal relay (``_SignalRelay``: never from the handler)."""
    global _relay
    if _relay is None:
        _relay = _SignalRelay()
    relay = _relay
    stop = threading.Event()
    relay.target = (stop, quiet)
    armed = [False]

    def handler(signum: int, _frame: FrameType | None) -> None:
        if bound_s is not None and not armed[0]:
            armed[0] = True
            faulthandler.dump_traceback_later(bound_s, exit=True)
        relay.notify(signum)

    signal.signal(signal.SIGINT, handler)
    signal.signal(signal.SIGTERM, handler)
    signal.signal(signal.SIGHUP, handler)
    return stop


def wait_for(stop: threading.Event, failed: threading.Event | None = None) -> bool:
    """Block the main thread until ``stop`` (a signal) or ``failed`` (a thread's guard) is
    set, waking up so signal handlers can run. True when a thread failed."""
    while not stop.wait(0.1):
        if failed is not None and failed.is_set():
            return True
    return False


CLI_CONNECT_TIMEOUT_S = 2.0
"""A command (``fleet estop`` included) fails this fast when no router answers: a stop that
waits 10 s for a router that is not there is worse than a clear error at once."""


def add_inventory_options(parser: argparse.ArgumentParser) -> None:
    """``--inventory``, ``--domain`` and ``--endpoint``: every command takes them."""
    parser.add_argument(
        "--inventory",
        default=DEFAULT_INVENTORY,
        help="fleet description (default ./inventory.toml)",
    )
    parser.add_argument(
        "--domain", type=int, default=None, help="override the inventory's DDS domain id"
    )
    parser.add_argument(
        "--endpoint",
        action="append",
        default=None,
        help="override the inventory's Zenoh endpoints (repeatable), e.g. tcp/127.0.0.1:7447",
    )
    parser.add_argument(
        "--principal",
        default=None,
        help="who this process acts as (default: $D1_FLEET_PRINCIPAL, else the process's own: "
        "operator for the CLI, coordinator, viewer, sim, router, the arms' agent)",
    )
    parser.add_argument(
        "--connect-timeout",
        type=float,
        default=CLI_CONNECT_TIMEOUT_S,
        metavar="S",
        help=f"how long a command waits for the router (default {CLI_CONNECT_TIMEOUT_S:g} s)",
    )
    parser.add_argument("--log-level", default="INFO")
    parser.add_argument(
        "--log-file",
        default=None,
        metavar="PATH",
        help="append the log to PATH instead of stderr (reopened when logrotate moves it)",
    )
    parser.add_argument(
        "--log-format",
        choices=LOG_FORMATS,
        default="text",
        help="text (default) or json: one object per line with time (UTC), level, logger, "
        "thread, message, role and pid",
    )


PRINCIPAL_ENV = "D1_FLEET_PRINCIPAL"


def inventory_from_args(args: argparse.Namespace, principal: str = "operator") -> Inventory:
    """Load the inventory, apply the command-line overrides, and set who this process acts as:
    ``--principal``, else $D1_FLEET_PRINCIPAL, else ``principal`` (the process's default)."""
    inventory = load_inventory(args.inventory)
    if args.domain is not None:
        inventory = inventory.with_domain(args.domain)
    if args.endpoint:
        inventory = inventory.with_endpoints(args.endpoint)
    # $D1_FLEET_PRINCIPAL is the user's identity: it never renames the fleet's own processes.
    from_env = os.environ.get(PRINCIPAL_ENV) if principal == "operator" else None
    chosen = getattr(args, "principal", None) or from_env or principal
    try:
        return inventory.with_principal(chosen)
    except ValueError as exc:
        raise InventoryError(f"--principal: {exc}") from None
