"""Device drivers: one async state machine per device kind, each over a :class:`HostPort`."""
