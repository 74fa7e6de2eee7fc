"""What the tests, the benchmarks (``bench/``) and the fuzz targets (``fuzz/``) share: the
fleet harness of real processes on loopback (``harness.py``), the hostile inputs
(``hostile.py``), the robot kinds as the safety tests drive them (``kinds.py``), a headless
Chromium (``browser.py``), a Foxglove client, a G1 on Unitree's own SDK (``sdk_g1.py``), the
D1 spec's golden strings, the bad-file tables, payload samples and key-space collectors, a run's
date, machine and load (``runinfo.py``) and the network lab's row records and their table
(``labrows.py``).

Nothing here imports ``tests/``, and ``bench/`` and ``fuzz/`` import only this package, never
``tests/``. Not part of the product: the wheel ships ``fleet``, ``edge_agent`` and ``viewer``
only (tests/e2e/test_packaging.py)."""
