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
    """The D1-550 URDF per inventory arm: its joints as plain-Python TF frames
    (``fleet/ros2/frames.py``), read once from the viewer's kinematic model."""

    def __init__(self, inventory: Inventory) -> None:
        from fleet.record.layout import layout_of
        from fleet.ros2.frames import ArmTree, JointFrame, wire_to_q
        from fleet.scene3d import kinematics as k

        self.layout = layout_of(inventory)
        self.model = model = k.ArmModel.from_urdf(k.load_urdf())
        self.urdf_text = k.URDF_PATH.read_text()
        self.joint_names: Sequence[str] = k.Q_JOINTS
        joints = []
        for i in range(1, len(model.links)):
            origin = model.origin[i]
            w, x, y, z = (float(v) for v in k.matrix_to_wxyz(origin[:3, :3]))
            joints.append(
                JointFrame(
                    model.links[model.parent[i]],
                    model.links[i],
                    (float(origin[0, 3]), float(origin[1, 3]), float(origin[2, 3])),
                    (x, y, z, w),
                    model.kind[i],
                    (float(model.axis[i][0]), float(model.axis[i][1]), float(model.axis[i][2])),
                    model.q_index[i],
                )
            )
        self.tree = ArmTree(joints)
        self._wire_to_q = wire_to_q
        self._bases = {}
        for arm, p in self.layout.arms.items():
            m = k.base_transforms(p.base_xyz, p.base_rpy_deg)[0]
            w, x, y, z = (float(v) for v in k.matrix_to_wxyz(m[:3, :3]))
            self._bases[arm] = (float(m[0, 3]), float(m[1, 3]), float(m[2, 3]), x, y, z, w)

    def urdf(self, arm: str) -> str:
        """The URDF as shipped (RViz's RobotModel adds the TF prefix ``<arm>``)."""
        return self.urdf_text

    def q(self, arm: str, angles_deg: Sequence[float]) -> list[float]:
        """The URDF joint values of ``arm`` at ``angles_deg``."""
        p = self.layout.arms[arm]
        return self._wire_to_q(angles_deg, p.joint_sign, (p.gripper_closed_deg, p.gripper_open_deg))

    def static_transforms(self, arm: str) -> list[Any]:
        """World -> base, then every fixed joint's parent -> child (frames ``<arm>/<link>``)."""
        from fleet.ros2.messages import Transform

        root = f"{arm}/{self.model.links[0]}"
        b = self._bases[arm]
        out = [Transform("world", root, b[:3], b[3:])]
        for j, pose in zip(self.tree.fixed, self.tree.static_poses(), strict=True):
            out.append(Transform(f"{arm}/{j.parent}", f"{arm}/{j.child}", pose[:3], pose[3:]))
        return out

    def moving_frames(self, arm: str) -> list[tuple[str, str]]:
        """(parent, child) of every moving joint, in the order of ``moving_poses``."""
        return [(f"{arm}/{j.parent}", f"{arm}/{j.child}") for j in self.tree.moving]

    def moving_poses(self, arm: str, q: Sequence[float]) -> list[Any]:
        """x y z qx qy qz qw of every moving joint at URDF joint values ``q``."""
        return self.tree.poses(q)


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
