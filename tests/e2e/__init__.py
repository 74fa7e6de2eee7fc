"""End-to-end tests: real processes, routers, DDS participants and servers on loopback."""
