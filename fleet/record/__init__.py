"""Recording the key space to MCAP and playing it back (``fleet record``, ``fleet replay``)."""
