"""Who may do what on the fleet's key space, at run time: the router's access control, TLS and
password sessions, and the test CA (``fleet certs``). The inventory's security sections (roles,
principals, modes) are ``fleet/security_config.py``, below the inventory: this package imports
the inventory, never the other way round. See docs/operations/security.md."""
