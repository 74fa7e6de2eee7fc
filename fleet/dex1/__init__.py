"""The Unitree Dex1-1 gripper as a fleet device: IDL types (both families), pure codec, grip
detection, agent relay and simulator."""
