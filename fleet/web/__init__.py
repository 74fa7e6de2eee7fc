"""What every web-facing port of the fleet shares: the per-run token, the Origin allow-list
(``access.py``) and the bounded log of refusals (``refusals.py``); the viewer and the Foxglove
gate both use them."""
