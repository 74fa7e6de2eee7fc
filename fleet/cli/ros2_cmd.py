"""``fleet ros2``: the fleet on rmw_zenoh's wire (fleet/ros2/node.py), with the D1-550's URDF
and forward kinematics of ``fleet/scene3d`` (the viewer draws with the same) as the arms' model."""

from __future__ import annotations

import argparse
import logging
from collections.abc import Callable, Sequence
from typing import Any

from fleet.guard import EXIT_THREAD_FAILED
from fleet.inventory import Inventory
from fleet.observe import Observed, add_observe_options
from fleet.runtime import inventory_from_args, shutdown_event, wait_for

log = logging.getLogger("fleet")


def register(
    sub: argparse._SubParsersAction, add_common: Callable[[argparse.ArgumentParser], None]
) -> None:  # type: ignore[type-arg]
    """Add ``ros2``."""
    parser = sub.add_parser(
        "ros2",
        help="speak ROS 2 (rmw_zenoh) on the fleet's router: joint_states, robot_description, "
        "tf, diagnostics, Trigger stops",
    )
    add_common(parser)
    add_observe_options(parser)
    parser.set_defaults(run=run_ros2)


class UrdfArms:
    """The D1-550 URDF and its forward kinematics (``fleet/scene3d``), per inventory arm."""

    def __init__(self, inventory: Inventory) -> None:
        from fleet.record.layout import layout_of
        from fleet.scene3d import kinematics
        from fleet.scene3d.frames3d import ArmFrames

        self._k = kinematics
        self.frames = ArmFrames.load(layout_of(inventory))
        self.joint_names: Sequence[str] = kinematics.Q_JOINTS

    def urdf(self, arm: str) -> str:
        """The URDF as shipped (RViz's RobotModel adds the TF prefix ``<arm>``)."""
        return self.frames.urdf_text

    def _q(self, arm: str, angles_deg: Sequence[float]) -> Any:
        p = self.frames.layout.arms[arm]
        grip = (p.gripper_closed_deg, p.gripper_open_deg)
        return self._k.wire_to_q([list(angles_deg)], p.joint_sign, grip)

    def q(self, arm: str, angles_deg: Sequence[float]) -> list[float]:
        """The URDF joint values of ``arm`` at ``angles_deg``."""
        return [float(v) for v in self._q(arm, angles_deg)[0]]

    def transforms(self, arm: str, angles_deg: Sequence[float]) -> list[Any]:
        """World -> base, then every joint's parent -> child (frames ``<arm>/<link>``), as the
        Foxglove bridge computes them (fleet/scene3d/frames3d.py)."""
        import numpy as np

        from fleet.ros2.messages import Transform

        k, model = self._k, self.frames.model
        p = self.frames.layout.arms[arm]
        links = k.forward(model, self._q(arm, angles_deg))[0]
        base = k.base_transforms(p.base_xyz, p.base_rpy_deg)[0]
        names = [f"{arm}/{name}" for name in model.links]
        pairs = [("world", names[0], base)]
        for i in range(1, len(names)):
            local = np.linalg.solve(links[model.parent[i]], links[i])  # parent-from-child
            pairs.append((names[model.parent[i]], names[i], local))
        out = []
        for parent, child, m in pairs:
            w, x, y, z = (float(v) for v in k.matrix_to_wxyz(m[:3, :3]))
            xyz = (float(m[0, 3]), float(m[1, 3]), float(m[2, 3]))
            out.append(Transform(parent, child, xyz, (x, y, z, w)))
        return out


def run_ros2(args: argparse.Namespace) -> int:
    """Serve the fleet to ROS 2 until SIGINT/SIGTERM."""
    from fleet.ros2.node import Ros2Node

    inventory = inventory_from_args(args, "ros2")
    if not getattr(args, "principal", None):
        inventory = inventory.with_principal(inventory.ros2.principal)
    stop = shutdown_event()
    with Ros2Node(inventory, UrdfArms(inventory)) as node:
        section = inventory.ros2
        print(
            f"d1-fleet ros2: ROS_DOMAIN_ID={section.domain_id}, "
            f"{len(inventory.arms)} arms, {len(inventory.devices)} devices, "
            f"stop service /{inventory.fleet}/estop (Ctrl-C stops)",
            flush=True,
        )
        with Observed(
            node.session, inventory, "ros2", args.metrics_port, collectors=lambda: _collectors(node)
        ):
            failed = wait_for(stop, node.failed)
    if failed:
        log.error("%s: the ROS 2 node stopped; restart it", node.guard.failure)
        return EXIT_THREAD_FAILED
    return 0


def _collectors(node: Any) -> list[Any]:
    from fleet.metrics import FunctionCollector, counter

    def collect() -> list[Any]:
        return [
            counter("d1_ros2_published", "ROS messages published", [], [([], node.published)]),
            counter("d1_ros2_dropped", "samples dropped at a full inbox", [], [([], node.dropped)]),
            counter("d1_ros2_bad", "undecodable key-space samples", [], [([], node.bad)]),
            counter(
                "d1_ros2_bad_requests",
                "Trigger requests refused or ignored (malformed, flood)",
                [],
                [([], node.bad_requests)],
            ),
            counter("d1_ros2_stops", "stops issued from ROS", [], [([], node.stops)]),
        ]

    return [FunctionCollector(collect)]
