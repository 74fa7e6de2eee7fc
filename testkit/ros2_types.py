"""ROS 2 Jazzy's types as an implementation that is not ours sees them (rosbags' type store),
and the public RIHS01 hash of each type the fleet publishes."""

from __future__ import annotations

from rosbags.typesys import Stores, get_types_from_msg, get_typestore

STORE = get_typestore(Stores.ROS2_JAZZY)
# rosbags' store holds messages only: the Trigger response's fields, under a message name.
STORE.register(get_types_from_msg("bool success\nstring message", "std_srvs/msg/TriggerResponse"))

# Public values seen in ROS installs' own output and generated code (``ros2 topic info -v``,
# rosidl's *__description.c), as collected by the search tools: the hash of each type.
PUBLIC_HASHES = {
    "sensor_msgs/msg/JointState": (
        "a13ee3a330e346c9d87b5aa18d24e11690752bd33a0350f11c5882bc9179260e"
    ),
    "std_msgs/msg/String": "df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18",
    "tf2_msgs/msg/TFMessage": "e369d0f05a23ae52508854b66f6aa0437f3449d652e8cbf22d5abe85d020f087",
    "diagnostic_msgs/msg/DiagnosticArray": (
        "5a8a36efb05fb25070fa0fb3810290c0e6cd4862b54a8fb975a1ee8dc55a333e"
    ),
    "std_srvs/srv/Trigger": "eeff2cd6fa5ad9d27cdf4dec64818317839b62f212a91e6b5304b634b2062c5f",
}
