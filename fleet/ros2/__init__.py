"""ROS 2 without a bridge: the fleet on rmw_zenoh's own wire, on the fleet's session.

| module | job |
|---|---|
| ``cdr.py`` | pure CDR (little endian, 4-byte encapsulation header): writer and bounded reader |
| ``messages.py`` | pure encoders of the ROS messages we publish, the Trigger service's CDR |
| ``contract.py`` | pure rmw_zenoh contract: type names and RIHS01 hashes, data keys, liveliness
  tokens with QoS, the 33-byte attachment, GIDs |
| ``config.py`` | the inventory's ``[ros2]`` section |
| ``node.py`` | ``fleet ros2``: key space -> ROS topics, Trigger services -> fleet stops |
"""
