"""Pure tests: no process, no socket, no Zenoh session, no DDS participant (see conftest.py)."""
