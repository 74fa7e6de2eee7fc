"""Who wrote a DDS sample, and whether the agent trusts it: one policy for arms and devices."""
