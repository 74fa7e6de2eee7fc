"""``make bench``: the fleet's latency and cost, side by side with raw DDS and Zenoh.

Run it as ``python -m bench`` from the repository root (it is not an installed package: it
reuses ``testkit/harness.py`` for DDS domains and ports).
"""
