"""The Unitree G1 humanoid's high-level motion service as a fleet device: ``rt/sportmodestate``
relayed, LocoClient RPC over DDS, stop action (stop_move or damp), simulator."""
