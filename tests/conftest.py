"""Shared test settings and rigs: hypothesis is derandomised so CI runs are reproducible, and
the fixtures below start rfhoming commands with deadlines and a guaranteed stop (tests/rigs.py).

Profiles: ``rfhoming`` (the default: derandomised, 150 examples), ``quick`` (the same with 40
examples: the quick loop ``-m "not slow"`` loads it) and ``fuzz`` (random seeds,
20,000 examples a test) for long hunts: ``python bench/fuzz.py --hypothesis`` or
``RFHOMING_HYPOTHESIS_PROFILE=fuzz python -m pytest tests/test_frames.py``.
"""

import contextlib
import os
import signal
from collections.abc import Callable, Iterator
from typing import Any

import pytest
import rigs
from hypothesis import HealthCheck, settings

# A suite started in the background (`nohup ... &`, a CI runner's job) has SIGINT ignored, and
# every child would inherit that: the tests that end a command with Ctrl-C need it back. A handler
# here (not an ignore) leaves the children the default on exec.
if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
    signal.signal(signal.SIGINT, signal.default_int_handler)

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
settings.register_profile("quick", parent=settings.get_profile("rfhoming"), max_examples=40)
settings.load_profile(os.environ.get("RFHOMING_HYPOTHESIS_PROFILE", "rfhoming"))


def pytest_configure(config: pytest.Config) -> None:
    """The quick loop (``-m "not slow"``) tries 40 examples a property test, the full suite 150
    (tests that set their own ``max_examples`` keep it): the loop catches what breaks a property
    outright, CI's full run searches further. ``RFHOMING_HYPOTHESIS_PROFILE`` wins over both."""
    if "RFHOMING_HYPOTHESIS_PROFILE" not in os.environ and (config.option.markexpr or "").split() == ["not", "slow"]:
        settings.load_profile("quick")


LONGEST_FIRST = (
    "test_docs.py", "test_campaigns.py", "test_replay_run.py", "test_c_reference.py", "test_locate_robust.py",
    "test_host_io.py", "test_radio_profile.py", "test_sitebus_hostile.py",  # the quick loop's longest
    "test_typing.py", "test_plan_timing.py", "test_s4_air.py", "test_lossless_replay.py", "test_mcap_frames.py", "test_locate.py",
    "test_run_cli.py", "test_vendor_clients.py", "test_fastdds.py", "test_ros2_live.py", "test_planning.py",
    "test_sitebus.py", "test_ros2_emulated.py", "test_rclpy.py", "test_homing.py", "test_foxglove_spec.py",
)
"""Test files by their measured time in the full suite, longest first (docs/testing.md, "The
suite's time"). The two xdist workers take whole files (``--dist loadfile``) in collection order
(``--no-loadscope-reorder``): a long file taken last would run alone at the end while the other
worker idles, so these start first and the many short files fill in behind them. Files not
named keep pytest's order after these; a stale entry only costs balance, never a test."""


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    rank = {name: k for k, name in enumerate(LONGEST_FIRST)}
    items.sort(key=lambda item: rank.get(item.path.name, len(rank)))  # stable: each file's own order is kept


@pytest.fixture
def emulated() -> Iterator[Callable[..., rigs.World]]:
    """``emulated(SCENARIO, *ARGS, link_dir=..., devices=...)`` starts ``rfhoming emulate`` and
    returns it with its endpoints read (``world.endpoints``, ``world.path("aoa")``); every world
    started is stopped after the test, pass or fail (SIGINT, SIGTERM, SIGKILL)."""
    with contextlib.ExitStack() as worlds:
        yield lambda *args, **kw: worlds.enter_context(rigs.emulate(*args, **kw))


@pytest.fixture
def spawn() -> Iterator[Callable[..., rigs.Child]]:
    """``spawn(*ARGS)`` starts ``rfhoming ARGS`` in the background (``argv0=`` for another
    program); read it with ``child.line(deadline_s)``; stopped after the test like a world."""
    with contextlib.ExitStack() as children:
        def start(*args: Any, argv0: list[str] = rigs.RFHOMING, **kw: Any) -> rigs.Child:
            return children.enter_context(rigs.Child([*argv0, *map(str, args)], **kw))

        yield start


@pytest.fixture
def cli() -> Callable[..., Any]:
    """``cli(*ARGS, timeout_s=...)`` runs ``rfhoming ARGS`` to its end (rigs.run): a
    CompletedProcess; past the timeout the command is killed and the test fails naming it."""
    return rigs.run
