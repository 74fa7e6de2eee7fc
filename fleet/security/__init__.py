"""Who may do what on the fleet's key space: principals and roles, TLS and passwords, the
router's access control, and the test CA (``fleet certs``). See docs/operations/security.md."""
