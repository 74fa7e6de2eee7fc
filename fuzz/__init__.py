"""Coverage-guided fuzzing of every decoder of hostile input (``make fuzz``; atheris).

One module per target; each defines ``check(data: bytes)`` (raises AssertionError, or lets an
unexpected exception through, when its property is broken) and ``seeds()`` (the seed corpus).
``python -m fuzz.run`` runs them under atheris with a time budget each; the same ``check``
functions replay the seed corpus in the normal test suite (``tests/unit/test_fuzz_targets.py``), so
a target cannot rot without ``make test`` noticing.
"""

TARGETS = (
    "d1_message",
    "d1_command",
    "keyspace",
    "sim_fault",
    "inventory",
    "choreo",
    "agent_plan",
)
"""Every fuzz target: a module ``fuzz.<name>``."""
