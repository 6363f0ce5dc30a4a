"""A loss is never only a counter: one warning naming the device when it first rises, and every
end-of-run summary lists the nonzero losses; a live port's queue still drops, a file's waits."""

from __future__ import annotations

import asyncio
import logging
import uuid

from rfhoming.host import losses
from rfhoming.host.drivers.aoa import AoaDriver
from rfhoming.host.drivers.common import BoundedStream
from rfhoming.host.ports import HostPort
from rfhoming.host.session import health


def _warnings(caplog, device: str) -> list[str]:
    return [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING and device in r.getMessage()]


def test_a_live_queue_that_drops_says_so_once_and_in_the_counters(caplog):
    """Old code: queue_dropped rose in silence, found only by whoever read the counters."""
    name = f"west-{uuid.uuid4().hex[:6]}"
    driver = AoaDriver(HostPort("/dev/null-not-opened", name=name))
    assert driver.out.get_nowait() is None  # a consumer reads the stream
    for k in range(1500):
        driver.out.put(k)
    caplog.set_level(logging.WARNING)
    first = health([driver])
    assert first[0]["losses"] == {"queue_dropped": 500}
    said = _warnings(caplog, name)
    assert len(said) == 1 and "queue_dropped" in said[0] and "consumer" in said[0]
    driver.out.put(0)
    assert health([driver])[0]["losses"] == {"queue_dropped": 501}
    assert len(_warnings(caplog, name)) == 1  # once, not at every look


def test_a_loss_is_warned_of_while_the_run_goes_on(caplog):
    caplog.set_level(logging.WARNING)
    counters = {"device": "east", "dropped_bytes": 0, "decoder.drop.crc": 3, "bytes_in": 10}

    async def run() -> list[str]:
        watch = asyncio.create_task(losses.watch(lambda: [counters], period=0.01, warnings=losses.LossWarnings()))
        await asyncio.sleep(0.05)
        before = _warnings(caplog, "east")
        counters["dropped_bytes"] = 4096
        for _ in range(100):
            await asyncio.sleep(0.01)
            if _warnings(caplog, "east"):
                break
        watch.cancel()
        return before

    assert asyncio.run(run()) == []  # a malformed input is no loss of the host's
    said = _warnings(caplog, "east")
    assert len(said) == 1 and "dropped_bytes = 4096" in said[0] and "buffer" in said[0]


def test_a_file_fills_over_the_bound_and_waits_where_a_live_port_drops():
    stream: BoundedStream[int] = BoundedStream(4)
    stream.get_nowait()
    with stream.filling():  # one recorded chunk of six items
        for k in range(6):
            stream.put(k)
    assert len(stream) == 6 and stream.dropped == 0

    async def wait_for_room() -> bool:
        waiting = asyncio.create_task(stream.room())
        await asyncio.sleep(0.01)
        blocked = not waiting.done()
        while len(stream) >= 4:
            await stream.get()
        await asyncio.wait_for(waiting, 1.0)
        return blocked

    assert asyncio.run(wait_for_room())
    for k in range(10):  # live: the oldest go, counted
        stream.put(k)
    assert len(stream) == 4 and stream.dropped == 9  # 3 were waiting: 1 fitted


def test_a_stream_nobody_reads_never_holds_a_file_up():
    stream: BoundedStream[int] = BoundedStream(2)
    with stream.filling():
        for k in range(5):
            stream.put(k)
    assert len(stream) == 2 and stream.dropped == 0
    asyncio.run(asyncio.wait_for(stream.room(), 1.0))
