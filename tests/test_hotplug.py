"""Hot-plug: an unplugged device is reopened as soon as its path is back, not when a doubling
back-off next looks; a device that is present but fails to open keeps the back-off. Time here
is virtual (a fake clock behind the watcher's sleep) or counted in events, never wall speed."""

from __future__ import annotations

import asyncio
from pathlib import Path

import pytest

from rfhoming.emulator.faults import Fault
from rfhoming.emulator.runtime import Emulator
from rfhoming.emulator.scenario import load
from rfhoming.host import hotplug
from rfhoming.host.drivers.aoa import AoaDriver
from rfhoming.host.ports import HostPort, PortError, reopen


class Clock:
    """Virtual time: the watcher's sleeps advance it; ``present(t)`` says whether the device is there."""

    def __init__(self, present) -> None:
        self.t = 0.0
        self.present = present
        self.sleeps: list[float] = []

    async def sleep(self, s: float) -> None:
        self.sleeps.append(s)
        self.t += s
        await asyncio.sleep(0)

    def exists(self, _path: str) -> bool:
        return self.present(self.t)


class FakePort:
    """Opens when the clock says the device is there and ``works(t)``; records the attempt times."""

    def __init__(self, clock: Clock, works=lambda t: True) -> None:
        self.spec = self.name = "/dev/ttyACM0"
        self.clock, self.works, self.attempts = clock, works, []

    async def open(self) -> None:
        self.attempts.append(round(self.clock.t, 6))
        if not (self.clock.present(self.clock.t) and self.works(self.clock.t)):
            raise PortError("no device at /dev/ttyACM0")


@pytest.fixture
def clock(monkeypatch) -> Clock:
    clock = Clock(lambda t: True)
    monkeypatch.setattr(hotplug, "sleep", clock.sleep)
    monkeypatch.setattr(hotplug, "exists", clock.exists)
    return clock


async def test_a_3_s_unplug_is_reopened_within_half_a_second_of_the_return(clock: Clock) -> None:
    clock.present = lambda t: t >= 3.0
    port = FakePort(clock)
    await reopen(port)
    assert 3.0 <= clock.t <= 3.5 and port.attempts == [0.0, pytest.approx(clock.t)]
    assert set(clock.sleeps) == {hotplug.POLL_S}  # polled, no back-off step while it was gone


async def test_a_present_device_that_fails_to_open_keeps_the_doubling_back_off(clock: Clock) -> None:
    port = FakePort(clock, works=lambda t: t >= 12.0)  # there, but busy for 12 s
    await reopen(port)
    gaps = [round(b - a, 6) for a, b in zip(port.attempts, port.attempts[1:])]
    assert gaps == [0.2, 0.4, 0.8, 1.6, 3.2, 5.0, 5.0][:len(gaps)] and len(gaps) >= 6


async def test_a_device_that_returns_during_a_long_back_off_is_opened_at_once(clock: Clock) -> None:
    # busy for 10 s (the back-off grows to 5 s), then unplugged at 10.5 s and back at 11 s
    clock.present = lambda t: not 10.5 <= t < 11.0
    port = FakePort(clock, works=lambda t: t >= 10.0)
    await reopen(port)
    assert 11.0 <= clock.t <= 11.0 + hotplug.POLL_S + 1e-9


def test_only_local_paths_are_watched() -> None:
    assert hotplug.watchable("/dev/ttyUSB0") and hotplug.watchable("/tmp/rfhoming-x/aoa")
    assert not hotplug.watchable("socket://127.0.0.1:4000") and not hotplug.watchable("COM3")


async def test_the_emulators_unplug_is_reopened_at_the_first_poll_that_sees_it_back(tmp_path: Path,
                                                                                     monkeypatch) -> None:
    """Counted, not timed: while the pty is gone the host makes no open attempt, only polls;
    the first poll that finds it again is followed by the open that works."""
    sc = load("s0-open", seed=3, target=(3.0, 2.0))
    em = Emulator(sc, transport="pty", seed=3, speed=4.0, link_dir=tmp_path,
                  faults=[Fault.parse("unplug@aoa:at=2,for=3")])
    await em.start()
    em.task = asyncio.create_task(em.run())
    polls: list[bool] = []
    real_exists = hotplug.exists
    monkeypatch.setattr(hotplug, "exists", lambda path: polls.append(real_exists(path)) or polls[-1])
    port = HostPort(em.device("aoa").link.describe()["path"])
    opens: list[bool] = []
    real_open = port.open

    async def counted_open() -> None:
        try:
            await real_open()
        except PortError:
            opens.append(False)
            raise
        opens.append(True)

    port.open = counted_open
    driver = AoaDriver(port)
    task = asyncio.create_task(driver.run())
    try:
        async with asyncio.timeout(60):
            while not (driver.counters["reconnects"] == 1 and driver.state == "streaming"):
                await asyncio.sleep(0.05)
    finally:
        task.cancel()
        await asyncio.gather(task, return_exceptions=True)
        em.task.cancel()
        await asyncio.gather(em.task, return_exceptions=True)
        await em.close()
    assert opens == [True, False, True]  # first open; one try as it went; the open on its return
    assert polls.count(True) == 1 and polls[-1] is True and polls.count(False) >= 2
