"""Shared test settings: hypothesis is derandomised so CI runs are reproducible.

Profiles: ``rfhoming`` (the default: derandomised, 150 examples) and ``fuzz`` (random seeds,
20,000 examples a test) for long hunts: ``python bench/fuzz.py --hypothesis`` or
``RFHOMING_HYPOTHESIS_PROFILE=fuzz python -m pytest tests/test_frames.py``.
"""

import os

from hypothesis import HealthCheck, settings

settings.register_profile(
    "rfhoming",
    derandomize=True,
    deadline=None,
    max_examples=150,
    suppress_health_check=[HealthCheck.too_slow],
)
settings.register_profile(
    "fuzz",
    derandomize=False,
    deadline=None,
    max_examples=20_000,
    suppress_health_check=[HealthCheck.too_slow],
)
settings.load_profile(os.environ.get("RFHOMING_HYPOTHESIS_PROFILE", "rfhoming"))
