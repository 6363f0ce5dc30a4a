"""Shared test settings: hypothesis is derandomised so CI runs are reproducible."""

from hypothesis import HealthCheck, settings

settings.register_profile(
    "rfhoming",
    derandomize=True,
    deadline=None,
    max_examples=150,
    suppress_health_check=[HealthCheck.too_slow],
)
settings.load_profile("rfhoming")
