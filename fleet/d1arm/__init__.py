"""The D1 arm kind's side of the agent, beside the device kinds (``fleet/dex1``, ``fleet/g1``),
on the D1 codec (``fleet/d1``) and the kinds' contract (``fleet/devices``); it never imports the
agent core. The core builds it like every kind of its registry (``kind.py``: ``build``, from
what the core shares: its lock, each arm's write lock, its DDS participant and Zenoh session,
the synchronized-start thread) and serves the arms through ``server.py`` (``ArmServer``, the
arms' ``UnitServer``); the arms' DDS readers and writers (``link``) and Zenoh publishers
(``publishers``) are made here, on the core's participant and session.

Pure parts: the tracked state (``tracker``), key-space commands -> checked D1 commands and one
command in flight (``commands``), which written command an ack answers (``acks``), the one hold
recipe (``holds``), the sag check (``sag``). With I/O: the D1 writer (``writer``), the arm's
commands (``serving``), its slot (``slot``), contact detection at the edge (``contact_edge``).
"""
