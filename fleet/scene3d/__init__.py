"""The fleet in 3D, for every consumer: the D1-550's URDF (``assets/``) and forward kinematics
(``kinematics.py``), each arm's link frames as Foxglove transforms (``frames3d.py``), and the live
Foxglove bridge (``foxglove_bridge.py``). The viewer draws with it, ``fleet record`` writes its
3D channels, ``fleet ros2`` publishes ``/tf`` from it and ``fleet foxglove`` serves it; it never
imports any of them (nor the viewer)."""
