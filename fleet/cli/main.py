"""fleet: the fleet's command line. fleet <command> --help for each command.

Exit codes: 0 success; 1 a command was refused or failed on an arm; 2 usage or configuration
error (bad inventory, unknown arm); 3 an arm's agent or the router is unreachable.
"""

from __future__ import annotations

import argparse
import os
import sys
from importlib.metadata import PackageNotFoundError, version

from fleet.cli import (
    arm_commands,
    calibrate,
    choreo_cmds,
    deploy_cmd,
    doctor_cmd,
    foxglove_cmd,
    processes,
    record_cmds,
    ros2_cmd,
    safety_cmds,
    security_cmds,
    status,
    viewer_cmd,
    wire_tools,
)
from fleet.d1.errors import NetworkInterfaceError
from fleet.inventory import InventoryError
from fleet.runtime import LogFileError, add_inventory_options, setup_logging_from_args
from fleet.wire.session import RouterUnreachable

EXIT_OK, EXIT_FAILED, EXIT_USAGE, EXIT_UNREACHABLE = 0, 1, 2, 3


def build_parser() -> argparse.ArgumentParser:
    """The whole command tree."""
    parser = argparse.ArgumentParser(
        prog="fleet", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--version", action="version", version=f"fleet {_version()}")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for module in (
        processes,
        status,
        arm_commands,
        calibrate,
        safety_cmds,
        viewer_cmd,
        choreo_cmds,
        record_cmds,
        security_cmds,
        wire_tools,  # after processes: it adds `fleet sim fault`
        doctor_cmd,
        foxglove_cmd,
        ros2_cmd,
        deploy_cmd,
    ):
        module.register(sub, add_inventory_options)
    return parser


def _version() -> str:
    try:
        return version("d1-fleet")
    except PackageNotFoundError:  # run from a source tree that was never installed
        return "(not installed)"


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``fleet`` console script."""
    args = build_parser().parse_args(argv)
    try:
        setup_logging_from_args(args, role=args.command)
        return int(args.run(args))
    except (InventoryError, NetworkInterfaceError, LogFileError) as exc:
        print(f"fleet: {exc}", file=sys.stderr)
        return EXIT_USAGE
    except RouterUnreachable as exc:
        print(f"fleet: {exc}", file=sys.stderr)
        return EXIT_UNREACHABLE
    except KeyboardInterrupt:
        return EXIT_OK
    except BrokenPipeError:
        # `fleet status | head -2`: the reader left, which is no error of ours. Point stdout
        # at /dev/null so the interpreter's final flush does not raise again.
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return EXIT_OK


if __name__ == "__main__":
    sys.exit(main())
