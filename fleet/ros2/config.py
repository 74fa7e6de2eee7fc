"""The inventory's ``[ros2]`` section (``fleet ros2``), validated. Pure.

```toml
[ros2]
domain_id = 0                 # ROS_DOMAIN_ID of the ROS side (not the arms' DDS domain)
principal = "ros2"            # who `fleet ros2` acts as (role "ros2")
estop_callers = ["operator"]  # principals the router lets call the Trigger stop services
world_frame = "world"
frame_prefix = true           # TF frames "<id>/<link>" (several arms in one RViz)
distro = "jazzy"              # "humble": keys and tokens without type hashes (rmw_zenoh on Humble)
[ros2.namespaces]
a1 = "/lab/left_arm"          # default "/<fleet>/<id>"
```
"""

from __future__ import annotations

from typing import Literal

from msgspec import Struct, field

from fleet.ros2.contract import NameError_, check_namespace, default_namespace


class Ros2Section(Struct, frozen=True, forbid_unknown_fields=True):
    """``[ros2]``: the ROS 2 face of the fleet (docs/guide/ros2.md)."""

    domain_id: int = 0
    principal: str = "ros2"
    estop_callers: list[str] = field(default_factory=lambda: ["operator"])
    world_frame: str = "world"
    frame_prefix: bool = True
    distro: Literal["jazzy", "humble"] = "jazzy"
    """``jazzy`` (also Kilted, Rolling): RIHS01 type hashes; ``humble``: none."""
    namespaces: dict[str, str] = {}

    def namespace(self, fleet: str, unit: str) -> str:
        """The ROS namespace of arm or device ``unit``."""
        return self.namespaces.get(unit) or default_namespace(fleet, unit)


def check_section(section: Ros2Section, fleet: str, units: set[str], principals: set[str]) -> str:
    """ "" when ``section`` is usable, else why not (the inventory names the file and path)."""
    if not 0 <= section.domain_id <= 232:
        return f"domain_id {section.domain_id} is outside 0..232"
    unknown = sorted(set(section.namespaces) - units)
    if unknown:
        return f"namespaces: {', '.join(unknown)} is no arm or device"
    for unit in units:
        try:
            check_namespace(section.namespace(fleet, unit))
        except NameError_ as exc:
            return f"namespaces.{unit}: {exc}"
    missing = sorted(set(section.estop_callers) - principals)
    if missing:
        return f"estop_callers: {', '.join(missing)} is not a principal of the inventory"
    if not section.world_frame or "/" in section.world_frame:
        return "world_frame: a frame name without '/'"
    return ""
