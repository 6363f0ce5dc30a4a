"""Campaigns: many seeded homing runs and estimator simulations, reduced to the seed papers'
tables (``rfhoming campaign``).

This package is wiring, like the demo: it is the one place outside the tests where the host
stack and the emulator meet, and it joins them only through the emulator's in-process byte pipe
(:mod:`rfhoming.campaigns.closed_loop`), as the host would reach a dongle. ``host`` never imports it; ``rfhoming campaign`` (the application layer) runs it.
"""
