"""The D1 arm kind's own parts of the agent, pure (no DDS, no Zenoh, no threads): its tracked
state (``tracker``), key-space commands -> checked D1 commands and one command in flight
(``commands``), which written command an ack answers (``acks``), the one hold recipe
(``holds``) and the sag check (``sag``). They sit beside the device kinds (``fleet/dex1``,
``fleet/g1``) on the D1 codec (``fleet/d1``) and the kinds' contract (``fleet/devices``), and
never import the agent core; the core serves them through ``edge_agent/arm_server.py``.
"""
