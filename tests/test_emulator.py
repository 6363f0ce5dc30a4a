"""The emulator seen from outside: transports, seeds, faults, clocks, scenarios."""

from __future__ import annotations

import asyncio
import math
import os
import termios
from collections import Counter

import pytest
import serial
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from rfhoming.emulator.faults import Fault, FaultError
from rfhoming.emulator.runtime import Emulator
from rfhoming.emulator.scenario import ScenarioError, load, presets
from rfhoming.emulator.world import Target
from rfhoming.protocol.frames import FrameDecoder, Odometry, VelocityCommand, encode_frame
from rfhoming.protocol.uconnect import UConnectDecoder

FAST = math.inf


async def drain(end) -> bytes:
    data = b""
    while end.pending():
        data += await end.read()
    return data


def angles(data: bytes) -> list:
    return [i for i in UConnectDecoder().feed(data) if i.kind == "angle"]


def make(scenario: str = "s0-open", seed: int = 1, **kw) -> Emulator:
    return Emulator(load(scenario, seed=seed, target=(3.0, 2.0) if scenario == "s0-open" else None),
                    transport=kw.pop("transport", "pipe"), seed=seed, speed=kw.pop("speed", FAST), **kw)


@pytest.mark.parametrize("name", presets())
def test_every_preset_builds_and_runs(name: str) -> None:
    async def go() -> None:
        em = make(name)
        await em.start()
        await em.run(1.0)
        assert em.counters["steps"] == 100
        total = sum(d.link.counters["tx_bytes"] for d in em.devices)
        assert total > 0
        await em.close()

    asyncio.run(go())


def test_presets_cover_every_paper() -> None:
    assert {"s0-open", "s0-house", "s1-dock", "s2-a", "s2-b", "s2-c", "s2-d", "s2-e", "s3-arena", "s4-survey"} <= set(presets())


def test_scenario_errors_say_what_to_fix(tmp_path) -> None:
    with pytest.raises(ScenarioError, match="presets: .*s0-open"):
        load("s9-nowhere")
    bad = tmp_path / "bad.toml"
    bad.write_text('bounds = [0, 0, 1, 1]\n[radio]\nshadow = 3\n')
    with pytest.raises(ScenarioError, match="unknown keys \\['shadow'\\]"):
        load(str(bad))
    bad.write_text('bounds = [0, 0, 1, 1]\n[devices.x]\ntype = "toaster"\n')
    with pytest.raises(ScenarioError, match="type must be one of"):
        load(str(bad))
    bad.write_text("bounds = [0, 0")
    with pytest.raises(ScenarioError, match="not valid TOML"):
        load(str(bad))


def test_random_targets_follow_the_seed() -> None:
    a, b, c = (load("s0-open", seed=s).world.targets[0].position for s in (1, 1, 2))
    assert a == b != c


async def test_identical_seeds_identical_bytes() -> None:
    async def run(seed: int) -> list[bytes]:
        em = make(seed=seed)
        await em.start()
        base = em.device("base").link.host
        base.write(encode_frame(VelocityCommand(0, 1, 0, 300, 200, 5000)))
        await em.run(3.0)
        out = [await drain(d.link.host) for d in em.devices]
        await em.close()
        return out

    first, again, other = await run(5), await run(5), await run(6)
    assert first == again and first[0] != other[0]
    assert len(angles(first[0])) > 100


async def test_angles_agree_with_truth_within_noise() -> None:
    em = make()
    await em.start()
    await em.run(5.0)
    events = angles(await drain(em.device("aoa").link.host))
    truth = -math.degrees(math.atan2(2.0, 3.0))  # board sign: left is negative
    errors = [e.azimuth - truth for e in events]
    assert len(errors) > 150
    assert abs(sum(errors) / len(errors)) < 1.0
    assert max(map(abs, errors)) < 6 * 3.0 + 1
    await em.close()


def with_tags(em: Emulator, intervals_ms: list[float]) -> list[str]:
    """Replace the scenario's tags with one per interval, spread in front of the robot."""
    em.world.targets[:] = [Target(f"CCF9578E0D{i:02X}", "aoa_tag", (4.0, -3.0 + 2.0 * i), interval_ms=ms)
                           for i, ms in enumerate(intervals_ms)]
    return [t.id for t in em.world.targets]


async def test_four_tags_each_at_its_own_advertising_interval() -> None:
    em = make()
    ids = with_tags(em, [20, 100, 250, 1000])
    await em.start()
    await em.run(6.0)
    counts = Counter(e.instance_id for e in angles(await drain(em.device("aoa").link.host)))
    for tag, ms in zip(ids, (20, 100, 250, 1000)):
        assert counts[tag] == pytest.approx(6000 / ms, rel=0.2, abs=2)
    await em.close()


async def test_more_tags_than_the_link_carries_queue_then_drop() -> None:
    """115200 Bd carries ~175 +UUDF lines/s; six tags at 20 ms offer 300."""
    em = make()
    with_tags(em, [20] * 6)
    await em.start()
    await em.run(3.0)
    data = await drain(em.device("aoa").link.host)
    events = angles(data)
    fw = em.device("aoa").firmware
    assert len(data) <= 3.0 * 115200 / 10 + 64  # 10 bits a byte, never faster
    assert len(events) < 0.7 * 6 * 50 * 3 and fw.counters["tx_overflow"] > 0
    lateness = [em.t * 1000 - e.timestamp_ms for e in events[-20:]]
    assert min(lateness) > 200  # the last lines delivered were measured long before
    await em.close()


async def test_base_moves_the_true_robot_and_reports_odometry() -> None:
    em = make()
    await em.start()
    em.device("base").link.host.write(encode_frame(VelocityCommand(0, 1, 0, 500, 0, 5000)))
    await em.run(3.0)
    odometry = [r for r in FrameDecoder().feed(await drain(em.device("base").link.host)) if isinstance(r, Odometry)]
    assert em.world.robot.x == pytest.approx(0.5 * 3 - 0.5 * 0.5 / 2, abs=0.02)
    assert odometry[-1].x_mm / 1000 == pytest.approx(em.world.robot.x, abs=0.02)
    await em.close()


async def test_obstacle_stops_the_robot_and_sets_contact() -> None:
    em = make("s2-b")
    await em.start()
    em.device("base").link.host.write(encode_frame(VelocityCommand(0, 1, 0, 500, 0, 60000)))
    await em.run(8.0)
    assert em.world.robot.x < 2.0 - em.scenario.robot_radius + 0.05
    flags = [r.flags for r in FrameDecoder().feed(await drain(em.device("base").link.host)) if isinstance(r, Odometry)]
    assert flags[-1] & 2
    scans = em.device("base").firmware.counters
    assert scans["tx_dropped"] == 0
    await em.close()


async def test_lockstep_waits_for_the_host() -> None:
    em = make(lockstep=True, lockstep_timeout=0.05)
    await em.start()
    task = asyncio.create_task(em.run(1.0))
    base = em.device("base").link.host
    for _ in range(5):  # answer five control periods promptly
        while em.t < (_ + 1) * 0.1 - 1e-9:
            await asyncio.sleep(0)
        base.write(encode_frame(VelocityCommand(0, 1, 0, 0, 0, 500)))
    await task
    assert em.t == pytest.approx(1.0)
    assert em.counters["lockstep_timeouts"] == 5  # the five periods nobody answered
    await em.close()


def test_lockstep_needs_a_base() -> None:
    sc = load("s0-open")
    sc.devices = [d for d in sc.devices if d.type != "base"]
    with pytest.raises(ValueError, match="lockstep needs a robot base"):
        Emulator(sc, transport="pipe", lockstep=True)


@pytest.mark.parametrize(
    ("spec", "words"),
    [("nope", "unknown fault"), ("ber:x=1", "takes"), ("unplug:for=1", "needs one of at=S or after_bytes=N"),
     ("reboot:at=1,after_bytes=10", "needs one of"), ("baud:after_bytes=10", "needs \\['rate'\\]"),
     ("drop:rate=a", "not a number")],
)
def test_fault_specs_are_checked(spec: str, words: str) -> None:
    with pytest.raises(FaultError, match=words):
        Fault.parse(spec)


async def test_fault_on_unknown_device_is_refused() -> None:
    with pytest.raises(ValueError, match="unknown device"):
        make(faults=[Fault.parse("reboot@nope:at=1")])


@pytest.mark.parametrize("spec", ["ber:rate=2e-4", "drop:rate=2e-3", "garbage:every=0.5,len=40"])
async def test_byte_faults_cost_drops_never_a_crash(spec: str) -> None:
    em = make(faults=[Fault.parse(spec)])
    await em.start()
    em.device("base").link.host.write(encode_frame(VelocityCommand(0, 1, 0, 100, 0, 60000)))
    await em.run(6.0)
    aoa = UConnectDecoder()
    items = aoa.feed(await drain(em.device("aoa").link.host))
    frames = FrameDecoder()
    records = frames.feed(await drain(em.device("base").link.host))
    aoa_drops = sum(v for k, v in aoa.counters.items() if k.startswith(("drop", "unknown")))
    frame_drops = sum(v for k, v in frames.counters.items() if k.startswith("drop"))
    assert aoa_drops + frame_drops > 0
    assert sum(1 for i in items if i.kind == "angle") > 200
    assert sum(1 for r in records if r.kind == "odometry") > 250
    await em.close()


async def test_reboot_prints_startup_mid_session() -> None:
    em = make(faults=[Fault.parse("reboot@aoa:at=1")])
    await em.start()
    await em.run(2.0)
    kinds = [i.kind for i in UConnectDecoder().feed(await drain(em.device("aoa").link.host))]
    assert kinds.count("startup") == 2 and kinds.index("startup", 1) > 10
    await em.close()


async def test_after_bytes_faults_follow_the_host_not_the_clock() -> None:
    """``after_bytes``: nothing happens until the host writes, however long the world runs; then
    the reboot comes after that many bytes, and the next waits for the host's next write."""
    em = make(faults=[Fault.parse("reboot@aoa:after_bytes=2000"), Fault.parse("reboot@aoa:after_bytes=2000")])
    await em.start()
    aoa = em.device("aoa").link
    await em.run(5.0)
    quiet = await drain(aoa.host)
    assert quiet.count(b"+STARTUP") == 1 and len(quiet) > 4000  # the clock alone would have fired twice
    for _ in range(2):
        aoa.host.write(b"AT\r\n")
        await em.run(5.0)
        after = await drain(aoa.host)
        assert after.count(b"+STARTUP") == 1 and after.index(b"+STARTUP") >= 2000
    await em.run(5.0)
    assert (await drain(aoa.host)).count(b"+STARTUP") == 0  # both fired: nothing more
    await em.close()


async def _advance(em: Emulator, until: float) -> None:
    """Step the emulator to simulated time ``until``: the test keeps the clock, so a loaded
    machine changes nothing (a real-time run once raced a poll against a timed unplug)."""
    while em.t + 1e-9 < until:
        await em.step()
        await asyncio.sleep(0)  # the links' readers and writers run


async def _poll(port: serial.Serial, em: Emulator, seconds: float) -> bytes:
    """Step the emulator ``seconds`` of simulated time, reading what the port got after each step."""
    data = b""
    end = em.t + seconds
    while em.t + 1e-9 < end:
        await _advance(em, em.t + em.step_s)
        data += port.read(65536)
    return data


async def test_pty_unplug_and_replug_at_the_same_path(tmp_path) -> None:
    em = make(transport="pty", speed=5, faults=[Fault.parse("unplug@aoa:at=1,for=1")], link_dir=tmp_path)
    (endpoint, _) = await em.start()
    path = endpoint["path"]
    port = serial.Serial(path, 115200, timeout=0)
    before = await _poll(port, em, 0.9)
    await _advance(em, 1.2)
    assert not os.path.exists(path)
    with pytest.raises(serial.SerialException):
        port.read(100)  # the device went away under the host
    port.close()
    await _advance(em, 2.1)
    port = serial.Serial(path, 115200, timeout=0)
    after = await _poll(port, em, 1.0)
    assert len(angles(before)) > 10 and len(angles(after)) > 10
    assert em.device("aoa").link.counters["unplugs"] == 1
    port.close()
    await em.close()


async def test_baud_mismatch_is_garbage_until_the_host_follows(tmp_path) -> None:
    em = make(transport="pty", speed=5, faults=[Fault.parse("baud@aoa:at=0.5,rate=1000000")], link_dir=tmp_path)
    endpoints = await em.start()
    port = serial.Serial(endpoints[0]["path"], 115200, timeout=0)
    good = await _poll(port, em, 0.45)
    await _advance(em, 0.6)
    port.read(65536)
    garbage = await _poll(port, em, 1.0)
    port.baudrate = 1000000
    assert termios.tcgetattr(em.device("aoa").link.master)[5] == termios.B1000000
    port.read(65536)
    healed = await _poll(port, em, 1.0)
    assert len(angles(good)) > 5 and angles(garbage) == [] and len(garbage) > 100
    assert len(angles(healed)) > 20
    port.close()
    await em.close()


async def test_tcp_transport_serves_pyserial_socket_urls() -> None:
    em = make(transport="tcp", speed=20)
    endpoints = await em.start()
    assert endpoints[0]["url"].startswith("socket://127.0.0.1:")
    port = serial.serial_for_url(endpoints[0]["url"], timeout=0)
    port.write(b"AT+GMI\r")
    data = await _poll(port, em, 0.9)
    items = UConnectDecoder().feed(data)
    assert [i.text for i in items if i.kind == "info"] == ['"u-blox"']
    assert len([i for i in items if i.kind == "angle"]) > 10
    port.close()
    await em.close()


async def test_umrs_moves_the_board_and_the_host_must_follow(tmp_path) -> None:
    em = make(transport="pty", speed=5, link_dir=tmp_path)
    endpoints = await em.start()
    port = serial.Serial(endpoints[0]["path"], 115200, timeout=0)
    for command in (b"AT+UMRS=460800,2\r", b"AT&W\r", b"AT+CPWROFF\r"):
        port.write(command)
        await _poll(port, em, 0.1)
    await _poll(port, em, 0.5)  # the restart
    assert em.device("aoa").device_baud() == 460800
    garbage = await _poll(port, em, 0.6)
    port.baudrate = 460800
    port.read(65536)
    await _poll(port, em, 1.0)  # after the restart the board ignores the host for a second
    port.write(b"AT\r")
    healed = await _poll(port, em, 0.6)
    assert angles(garbage) == [] and len(garbage) > 50
    items = UConnectDecoder().feed(healed)
    assert any(i.kind == "final" and i.ok for i in items) and len([i for i in items if i.kind == "angle"]) > 5
    port.close()
    await em.close()


HOUSE = load("s0-house", seed=0).world


def _segment_distance(px: float, py: float, a: tuple[float, float], b: tuple[float, float]) -> float:
    ex, ey = b[0] - a[0], b[1] - a[1]
    s = min(max(((px - a[0]) * ex + (py - a[1]) * ey) / max(ex * ex + ey * ey, 1e-12), 0.0), 1.0)
    return math.hypot(a[0] + s * ex - px, a[1] + s * ey - py)


@settings(max_examples=300, deadline=None)
@given(st.floats(-7, 7), st.floats(-7, 7), st.floats(0.05, 0.6))
def test_collision_check_matches_every_edge_by_brute_force(x: float, y: float, radius: float) -> None:
    """The robot's collision check looks only at obstacles near it; brute force over every edge
    of the house agrees (away from a float-rounding tie)."""
    nearest = min(_segment_distance(x, y, a, b) for o in HOUSE.obstacles for a, b in o.edges())
    inside = any(o.contains(x, y) for o in HOUSE.obstacles)
    assume(inside or abs(nearest - radius) > 1e-9)
    assert HOUSE.collides(x, y, radius) == (inside or nearest < radius)


def _crosses(p, q, a, b) -> bool:
    """Segment p-q meets edge a-b (parametric form, both parameters in [0, 1])."""
    dx, dy, ex, ey = q[0] - p[0], q[1] - p[1], b[0] - a[0], b[1] - a[1]
    denom = dx * ey - dy * ex
    if abs(denom) <= 1e-12:
        return False
    wx, wy = a[0] - p[0], a[1] - p[1]
    t, u = (wx * ey - wy * ex) / denom, (wx * dy - wy * dx) / denom
    return 0 <= t <= 1 and 0 <= u <= 1


@settings(max_examples=300, deadline=None)
@given(st.floats(-6, 6), st.floats(-6, 6), st.floats(-6, 6), st.floats(-6, 6))
def test_obstacles_crossed_matches_every_edge_by_brute_force(px: float, py: float, qx: float, qy: float) -> None:
    """Line of sight looks only at obstacles whose box meets the segment's; brute force over
    every edge of every obstacle of the house counts the same obstacles."""
    p, q = (px, py), (qx, qy)
    expected = sum(any(_crosses(p, q, a, b) for a, b in o.edges()) for o in HOUSE.obstacles)
    assert HOUSE.obstacles_crossed(p, q) == expected
