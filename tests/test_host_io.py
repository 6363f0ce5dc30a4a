"""Host I/O against the emulator over ptys and TCP: ports, drivers, capture and replay."""

from __future__ import annotations

import asyncio
import errno
import math
import os
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

from rfhoming.emulator.faults import Fault
from rfhoming.emulator.runtime import Emulator
from rfhoming.emulator.scenario import load
from rfhoming.host.capture import CaptureWriter
from rfhoming.host.drivers.aoa import AoaDriver, AoaSetup, identify_dialect, looks_binary
from rfhoming.host.drivers.robot_base import BaseDriver
from rfhoming.host.drivers.rss import AntennaPowers, Associator, LossCounter, NodeClock, RssDriver
from rfhoming.host.outputs import part_of
from rfhoming.host.ports import HostPort, PortError, explain
from rfhoming.host.replay import ReplayPort, load_capture
from rfhoming.host.session import recorded_kind
from rfhoming.protocol import pcapng
from rfhoming.protocol.uconnect import Dialect


async def start(tmp_path: Path, scenario: str = "s0-open", *, speed: float = 4.0, faults: list[str] = (),
                transport: str = "pty", dialect: str | None = None) -> Emulator:
    sc = load(scenario, seed=3, target=(3.0, 2.0) if scenario == "s0-open" else None)
    if dialect:
        next(d for d in sc.devices if d.type == "xplr-aoa").options["dialect"] = dialect
    em = Emulator(sc, transport=transport, seed=3, speed=speed, link_dir=tmp_path,
                  faults=[Fault.parse(f) for f in faults])
    await em.start()
    em.task = asyncio.create_task(em.run())
    return em


async def stop(em: Emulator, *drivers_tasks: asyncio.Task) -> None:
    for task in drivers_tasks:
        task.cancel()
        await asyncio.gather(task, return_exceptions=True)
    em.task.cancel()
    await asyncio.gather(em.task, return_exceptions=True)
    await em.close()


def where(em: Emulator, device: str) -> str:
    endpoint = em.device(device).link.describe()
    return endpoint.get("path") or endpoint["url"]


async def until(predicate, timeout: float = 10.0) -> None:
    async with asyncio.timeout(timeout):
        while not predicate():
            await asyncio.sleep(0.02)


# -- ports ----------------------------------------------------------------------------------
async def test_missing_port_says_how_to_find_one() -> None:
    with pytest.raises(PortError, match="no device at /dev/nope.*rfhoming devices"):
        await HostPort("/dev/nope").open()


async def test_busy_port_says_who_to_close(tmp_path: Path) -> None:
    em = await start(tmp_path)
    first = HostPort(where(em, "aoa"))
    await first.open()
    with pytest.raises(PortError, match="busy"):
        await HostPort(where(em, "aoa")).open()
    await first.close()
    second = HostPort(where(em, "aoa"))
    await second.open()  # the lock went with the close
    await second.close()
    await stop(em)


def test_permission_denied_names_the_dialout_group() -> None:
    message = explain("/dev/ttyACM0", PermissionError(errno.EACCES, "Permission denied"))
    assert "dialout" in message and "usermod" in message


async def test_nothing_listening_on_tcp_names_the_emulator() -> None:
    with pytest.raises(PortError, match="rfhoming emulate --tcp"):
        await HostPort("socket://127.0.0.1:9").open()


# -- the AoA driver -------------------------------------------------------------------------
@pytest.mark.parametrize("dialect", ["1.0", "1.2", "2.x", "embed"])
async def test_setup_identifies_every_dialect(tmp_path: Path, dialect: str) -> None:
    em = await start(tmp_path, dialect=dialect)
    driver = AoaDriver(HostPort(where(em, "aoa")))
    angles = []  # the board's own events, as the driver's listeners see them (out holds readings)
    driver.listeners.append(lambda _device, _t, item: angles.append(item) if item.kind == "angle" else None)
    task = asyncio.create_task(driver.run())
    await until(lambda: driver.state == "streaming")
    assert driver.dialect is Dialect(dialect)
    await asyncio.wait_for(driver.out.get(), 10)
    assert (angles[-1].seq is not None) == (dialect in ("2.x", "embed"))
    await stop(em, task)


def test_dialect_identification_from_answers() -> None:
    assert identify_dialect('"NINA-B4-DF"', '"1.0.2-001"', "") is Dialect.V1_0
    assert identify_dialect("NINA-B411-40B", '"1.2.0-005"', "") is Dialect.V1_2
    assert identify_dialect("NINA-B411-40B", '"2.1.0-010"', "") is Dialect.V2
    assert identify_dialect("NINA-B411-40B", '"1.0.0"', '"u-locateEmbed","1.0.0"') is Dialect.EMBED


async def test_config_is_applied_stored_and_survives_reboot(tmp_path: Path) -> None:
    em = await start(tmp_path, faults=["reboot@aoa:at=4"])
    driver = AoaDriver(HostPort(where(em, "aoa")), AoaSetup(config={2: "dock-7", 1: 40}))
    task = asyncio.create_task(driver.run())
    await until(lambda: driver.counters["reboots"] == 1 and driver.state == "streaming", 15)
    while len(driver.out):  # events from before the set-up finished
        await driver.out.get()
    angles = []  # the board's own events (out holds readings)
    driver.listeners.append(lambda _device, _t, item: angles.append(item) if item.kind == "angle" else None)
    await asyncio.wait_for(driver.out.get(), 5)
    assert angles[-1].user_str == "dock-7"
    assert driver.counters["setups"] == 2
    assert em.device("aoa").firmware.saved.udfcfg[1] == 40
    await stop(em, task)


async def test_unplug_replug_reconnects_and_sets_up_again(tmp_path: Path) -> None:
    em = await start(tmp_path, faults=["unplug@aoa:at=2,for=1"])
    driver = AoaDriver(HostPort(where(em, "aoa")))
    task = asyncio.create_task(driver.run())
    await until(lambda: driver.counters["reconnects"] == 1 and driver.state == "streaming", 15)
    before = sum(driver.tags_heard.values())
    await until(lambda: sum(driver.tags_heard.values()) > before + 5)
    assert driver.counters["setups"] == 2 and driver.port.counters["disconnects"] == 1
    await stop(em, task)


@pytest.mark.slow
async def test_baud_mismatch_detected_reported_and_probed(tmp_path: Path) -> None:
    em = await start(tmp_path, faults=["baud@aoa:at=1.5,rate=460800"])
    driver = AoaDriver(HostPort(where(em, "aoa")), AoaSetup(garbage_timeout=1.0, probe_baud=True))
    task = asyncio.create_task(driver.run())
    await until(lambda: driver.counters["baud_mismatch"] >= 1, 15)
    assert "only garbage" in (driver.problem or "") and "AT+UMRS" in driver.problem
    await until(lambda: driver.port.baud == 460800 and driver.state == "streaming", 20)
    await stop(em, task)


async def test_identification_errors_degrade_and_the_field_count_decides(tmp_path: Path) -> None:
    em = await start(tmp_path, dialect="2.x")
    fw = em.device("aoa").firmware
    execute = fw._execute
    fw._execute = lambda line: fw._answer(ok=False) if line in ("AT+GMM", "AT+GMR", "ATI9") else execute(line)
    driver = AoaDriver(HostPort(where(em, "aoa")), AoaSetup(config={1: 30}))
    task = asyncio.create_task(driver.run())
    await until(lambda: driver.state == "streaming")
    assert driver.identity == {"model": "", "version": "", "software": ""}
    await asyncio.wait_for(driver.out.get(), 10)
    assert driver.dialect is Dialect.V2  # 10 fields: the guess (1.2) gave way
    await stop(em, task)


@pytest.mark.parametrize(("dialect", "restarts"), [("1.2", 1), ("2.x", 0)])
async def test_settings_read_back_restart_only_where_needed(tmp_path: Path, dialect: str, restarts: int) -> None:
    em = await start(tmp_path, dialect=dialect)
    driver = AoaDriver(HostPort(where(em, "aoa")), AoaSetup(config={2: "dock-7"}))
    task = asyncio.create_task(driver.run())
    await until(lambda: driver.state == "streaming")
    assert driver.counters["restarts"] == restarts
    while len(driver.out):
        await driver.out.get()
    angles = []  # the board's own events (out holds readings)
    driver.listeners.append(lambda _device, _t, item: angles.append(item) if item.kind == "angle" else None)
    await asyncio.wait_for(driver.out.get(), 5)
    assert angles[-1].user_str == "dock-7"
    assert em.device("aoa").firmware.saved.udfcfg[2] == "dock-7"  # stored either way
    await stop(em, task)


async def test_settings_the_family_lacks_are_skipped_not_fatal(tmp_path: Path) -> None:
    em = await start(tmp_path, dialect="1.2")
    driver = AoaDriver(HostPort(where(em, "aoa")), AoaSetup(config={10: 50, 6: 0}))
    task = asyncio.create_task(driver.run())
    await until(lambda: driver.state == "streaming")
    assert driver.counters["config_skipped"] == 1 and driver.counters["restarts"] == 0
    await stop(em, task)


async def test_a_silent_board_gets_a_hint(tmp_path: Path) -> None:
    em = await start(tmp_path)
    em.device("aoa").firmware.on_advertisement = lambda adv: None  # no tag advertising
    driver = AoaDriver(HostPort(where(em, "aoa")), AoaSetup(silence_timeout=1.0))
    task = asyncio.create_task(driver.run())
    await until(lambda: driver.counters["silent"] == 1)
    assert "not advertising" in driver.problem and "docs/hardware.md" in driver.problem
    await stop(em, task)


async def test_binary_output_is_told_from_a_baud_mismatch(tmp_path: Path) -> None:
    em = await start(tmp_path, dialect="embed")
    fw = em.device("aoa").firmware
    fw.saved.udfcfg[7] = fw.active.udfcfg[7] = fw.pending.udfcfg[7] = 2
    driver = AoaDriver(HostPort(where(em, "aoa")), AoaSetup(garbage_timeout=1.0))
    task = asyncio.create_task(driver.run())
    await until(lambda: driver.counters["binary_output"] >= 1, 15)
    assert "AT+UDFCFG=7,2" in driver.problem and driver.counters["baud_mismatch"] == 0
    # decoded, azimuth at payload byte 6 as the one public parser reads it ([BIN] in docs/protocol.md)
    await until(lambda: driver.counters["binary_events"] > 5 and len(driver.out) > 0, 15)
    first = driver.out.get_nowait()
    assert first.tag in driver.tags_heard and -90 <= first.clockwise_deg <= 90
    await stop(em, task)


def test_binary_payload_byte_6_is_the_azimuth() -> None:
    """The public parser reads the azimuth as a signed byte at payload offset 6 (docs/protocol.md)."""
    from rfhoming.firmware.xplr_aoa import C209_NAMESPACE, Advertisement, XplrAoaFirmware
    from rfhoming.protocol.uconnect.binary import BinaryDecoder
    fw = XplrAoaFirmware(dialect=Dialect.EMBED)
    fw.saved.udfcfg[7] = fw.active.udfcfg[7] = 2
    fw.read()
    fw.tick(100)
    fw.on_advertisement(Advertisement("CCF9578E0D8A", C209_NAMESPACE, -37.0, 4.0, -60, -61))
    frame = fw.read()
    assert frame[0] == 0xFE and frame[1] == 0x01 and int.from_bytes(frame[4 + 6:4 + 7], "little", signed=True) == -37
    (event,) = BinaryDecoder().feed(b"\x00\xfe" + frame[:5] + frame[5:])
    assert (event.instance_id, event.azimuth) == ("CCF9578E0D8A", -37)


async def test_setup_stops_a_streaming_board_first(tmp_path: Path) -> None:
    """A board still streaming +UUDF gets AT+UDFENABLE=0 before any other set-up command, as
    u-blox's own clients do ([AOACTL] in docs/protocol.md)."""
    em = await start(tmp_path)
    fw = em.device("aoa").firmware
    seen: list[bytes] = []
    receive = fw.receive
    fw.receive = lambda data: (seen.append(data), receive(data))[1]
    driver = AoaDriver(HostPort(where(em, "aoa")))
    task = asyncio.create_task(driver.run())
    await until(lambda: driver.state == "streaming", 15)
    sent = b"".join(seen)
    assert sent.index(b"AT+UDFENABLE=0\r") < sent.index(b"AT+GMM\r") < sent.index(b"AT+UDFENABLE=1\r")
    await stop(em, task)


async def test_board_filter_without_effect_is_reported(tmp_path: Path) -> None:
    """The driver checks that the on-board filter works (other tags stop), not only its read-back."""
    em = await start(tmp_path)
    fw = em.device("aoa").firmware
    fw.boot = lambda now_ms, boot=fw.boot: (boot(now_ms), fw.active.filters.update({2: []}))[0]  # ignores it
    driver = AoaDriver(HostPort(where(em, "aoa")), AoaSetup().with_tags(("000000000000",)))
    task = asyncio.create_task(driver.run())
    await until(lambda: driver.counters["board_filter_leaks"] >= 3, 15)
    assert driver.counters["restarts"] == 1 and len(driver.out) == 0  # the host filter is the backstop
    await stop(em, task)


async def test_embed_silence_names_the_namespace_filter(tmp_path: Path) -> None:
    em = await start(tmp_path, dialect="embed")
    em.device("aoa").namespace = "00112233445566778899"  # a home-made tag's namespace
    driver = AoaDriver(HostPort(where(em, "aoa")), AoaSetup(silence_timeout=1.0))
    task = asyncio.create_task(driver.run())
    await until(lambda: driver.counters["silent"] == 1, 15)
    assert "NINA-B4TAG" in driver.problem and "AT+UDFFILT=1,1" in driver.problem
    await stop(em, task)


async def test_text_that_is_not_uudf_is_told_from_a_baud_mismatch(tmp_path: Path) -> None:
    """Raw-IQ JSON debug lines are well-formed text: the baud rate is right, the output is not."""
    em = await start(tmp_path)
    fw = em.device("aoa").firmware
    fw.on_advertisement = lambda adv: fw._emit(b'\r\n{"iq":[12,-7,3,40,-2,11,9,-33,5,8],"ch":37}\r\n')
    driver = AoaDriver(HostPort(where(em, "aoa")), AoaSetup(garbage_timeout=1.0))
    task = asyncio.create_task(driver.run())
    await until(lambda: driver.counters["unknown_output"] >= 1, 15)
    assert "JSON" in driver.problem and '{"iq"' in driver.problem and driver.counters["baud_mismatch"] == 0
    await stop(em, task)


def test_garbage_does_not_look_like_binary_output() -> None:
    rng = np.random.default_rng(1)
    assert not any(looks_binary(rng.integers(0, 256, 512, dtype=np.uint8).tobytes()) for _ in range(200))
    frame = b"\xfe\x01\x11\x00" + bytes(17)
    assert looks_binary(b"junk" + frame * 3)


async def test_an_unread_stream_counts_no_loss(tmp_path: Path) -> None:
    """listen and capture read no queue: what the ring overwrites was never waited for."""
    em = await start(tmp_path)
    driver = AoaDriver(HostPort(where(em, "aoa")), queue_size=5)
    task = asyncio.create_task(driver.run())
    await until(lambda: sum(driver.tags_heard.values()) > 20)
    assert driver.health()["queue_dropped"] == 0
    await stop(em, task)


async def test_host_side_tag_filter(tmp_path: Path) -> None:
    em = await start(tmp_path)
    driver = AoaDriver(HostPort(where(em, "aoa")), AoaSetup(host_filter=frozenset({"000000000000"})))
    task = asyncio.create_task(driver.run())
    await until(lambda: driver.counters["filtered"] > 10)
    assert len(driver.out) == 0
    await stop(em, task)


async def test_aoa_over_tcp(tmp_path: Path) -> None:
    em = await start(tmp_path, transport="tcp")
    driver = AoaDriver(HostPort(where(em, "aoa")))
    task = asyncio.create_task(driver.run())
    event = await asyncio.wait_for(driver.out.get(), 10)
    assert abs(event.clockwise_deg + math.degrees(math.atan2(2, 3))) < 15
    await stop(em, task)


# -- RSS nodes and base ---------------------------------------------------------------------
def test_node_clock_unwraps_and_maps_to_host_time() -> None:
    clock = NodeClock()
    assert clock.to_host(4_294_000_000, 1000.010) == pytest.approx(1000.010)
    t = clock.to_host(32_704, 1001.010)  # 1 s later, across the u32 wrap
    assert t == pytest.approx(1000.010 + 1.0, abs=1e-6)
    assert clock.to_host(1_032_704, 1002.5) == pytest.approx(1002.010, abs=1e-6)  # arrived 0.49 s late


def test_loss_counter_counts_gaps_not_restarts() -> None:
    loss = LossCounter()
    for seq in (1, 2, 5, 6, 7, 65534, 65535, 0, 2):  # 7 -> 65534: a jump of ≥ 2^15 is a restart
        loss.see(3, seq)
    assert loss.lost == 2 + 1 and loss.received == 9  # 3, 4 and (across the wrap) 1
    fresh = LossCounter()
    for seq in (100, 101, 5, 6):  # the node restarted
        fresh.see(1, seq)
    assert fresh.lost == 0


def test_associator_groups_four_antennas_and_expires_partial_sets() -> None:
    a = Associator(window_s=0.05)
    assert a.add(1, 7, 0, -60.0, 10.0) == []
    assert a.add(1, 7, 2, -70.0, 10.001) == []
    assert a.add(1, 7, 1, -80.0, 10.002) == []
    (done,) = a.add(1, 7, 3, -75.0, 10.003)
    assert done.dbm == (-60.0, -80.0, -70.0, -75.0)
    a.add(1, 8, 0, -61.0, 11.0)
    (partial,) = a.add(1, 9, 0, -62.0, 11.1)
    assert partial.emitter_seq == 8 and partial.dbm[1:] == (None, None, None)


@pytest.mark.parametrize("sets", [True, False])
async def test_rss_driver_gives_four_antenna_powers(tmp_path: Path, sets: bool) -> None:
    em = await start(tmp_path, "s2-a")
    driver = RssDriver(HostPort(where(em, "rss")), use_antenna_sets=sets)
    task = asyncio.create_task(driver.run())
    readings = []
    while len(readings) < 20:
        r = await asyncio.wait_for(driver.out.get(), 10)
        if isinstance(r, AntennaPowers):
            readings.append(r)
    front = sum(r.dbm[0] for r in readings) / len(readings)
    assert all(front > sum(r.dbm[i] for r in readings) / len(readings) for i in (1, 2, 3))
    assert driver.loss.lost == 0 and driver.status
    await stop(em, task)


async def test_base_driver_stops_the_robot_on_an_exception(tmp_path: Path) -> None:
    em = await start(tmp_path)
    driver = BaseDriver(HostPort(where(em, "base")), command_timeout_ms=5000)
    task = asyncio.create_task(driver.run())
    await until(lambda: driver.latest is not None)
    with pytest.raises(RuntimeError):
        async with driver:
            driver.send_velocity(0.4, 0.0)
            await until(lambda: driver.latest.v > 0.2)
            raise RuntimeError("controller crashed")
    await until(lambda: em.device("base").firmware._target == (0.0, 0.0), 5)
    assert driver.counters["stops"] == 1
    await stop(em, task)


# -- capture and replay ---------------------------------------------------------------------
async def record(tmp_path: Path, seconds: float, faults: list[str] = ()) -> tuple[Path, dict[str, list]]:
    em = await start(tmp_path, faults=faults)
    capture = CaptureWriter(tmp_path / "run.pcapng")
    live: dict[str, list] = {}
    drivers = [AoaDriver(HostPort(where(em, "aoa"), taps=[capture.tap])),
               RssDriver(HostPort(where(em, "base"), taps=[capture.tap]))]
    capture.describe(drivers[0].port.name, kind="xplr-aoa")
    capture.describe(drivers[1].port.name, kind="rss-node")
    for d in drivers:
        d.listeners.append(lambda dev, t, item: live.setdefault(dev, []).append((t, item)))
    tasks = [asyncio.create_task(d.run()) for d in drivers]
    start_t = em.t
    await until(lambda: em.t > start_t + seconds, 30)
    await stop(em, *tasks)
    for d in drivers:
        d.drain()
    capture.close()
    return capture.path, live


async def replay(path: Path) -> dict[str, list]:
    interfaces, packets, _ = load_capture(path)
    out: dict[str, list] = {}
    drivers = []
    for i, iface in enumerate(interfaces):
        port = ReplayPort(iface.name, packets[i])
        d = AoaDriver(port) if recorded_kind(iface).name == "xplr-aoa" else RssDriver(port)
        d.listeners.append(lambda dev, t, item: out.setdefault(dev, []).append((t, item)))
        drivers.append(d)
    await asyncio.wait_for(asyncio.gather(*(d.run() for d in drivers)), 30)
    return out


async def test_replay_matches_writes_in_a_row_one_for_one() -> None:
    """Two writes between reads (the loop's brake mode, then its velocity): each recorded write
    is matched by its own replayed write, in order, and the answer after them is released."""
    packets = [pcapng.Packet(0, 1.0, b"brake", pcapng.OUTBOUND), pcapng.Packet(0, 1.1, b"velocity", pcapng.OUTBOUND),
               pcapng.Packet(0, 1.2, b"odometry", pcapng.INBOUND)]
    port = ReplayPort("base", packets)
    await port.open()
    port.write(b"brake")
    port.write(b"velocity")
    chunk = await asyncio.wait_for(port.read(), 1.0)
    assert chunk.data == b"odometry"
    assert port.counters["diverged"] == 0 and port.counters["unanswered"] == 0
    port = ReplayPort("base", packets)
    port.write(b"velocity")
    port.write(b"brake")  # the replayed host wrote in another order: both count
    await port.read()
    assert port.counters["diverged"] == 2


@pytest.mark.slow
async def test_capture_then_replay_gives_identical_records(tmp_path: Path) -> None:
    path, live = await record(tmp_path, 6.0, faults=["unplug@aoa:at=2,for=1", "reboot@aoa:at=4.5"])
    replayed = await replay(path)
    assert set(replayed) == set(live)
    for device in live:
        assert replayed[device] == live[device]
    kinds = [item.kind for _, item in live[str(tmp_path / "aoa")]]
    assert kinds.count("startup") >= 1 and kinds.count("angle") > 50


async def test_truncated_capture_replays_up_to_its_last_complete_block(tmp_path: Path) -> None:
    path, live = await record(tmp_path, 3.0)
    data = path.read_bytes()
    path.write_bytes(data[: len(data) - 37])  # killed mid-block
    interfaces, packets, torn = load_capture(path)
    assert 0 < torn
    replayed = await replay(path)
    for device, items in replayed.items():
        assert items == live[device][: len(items)]
        assert len(items) >= len(live[device]) - 10


async def test_capture_is_flushed_within_a_second(tmp_path: Path) -> None:
    writer = CaptureWriter(tmp_path / "live.pcapng", {"p": {"protocol": "rss"}})
    writer.tap("p", "in", 1.0, b"\x00abc\x00")
    await asyncio.sleep(1.2)
    _, packets, torn = pcapng.read_all(part_of(tmp_path / "live.pcapng").read_bytes())  # what a kill would leave
    assert [p.data for p in packets] == [b"\x00abc\x00"] and torn == 0
    writer.close()


@pytest.mark.skipif(shutil.which("tshark") is None, reason="tshark is not installed (apt-get install tshark)")
async def test_tshark_reads_a_capture(tmp_path: Path) -> None:
    path, live = await record(tmp_path, 2.0)
    done = subprocess.run(["tshark", "-r", str(path), "-T", "fields", "-e", "frame.interface_name",
                           "-e", "frame.p2p_dir", "-e", "frame.len"], capture_output=True, text=True,
                          env={**os.environ, "HOME": str(tmp_path)}, timeout=120)
    assert done.returncode == 0, done.stderr
    rows = [line.split("\t") for line in done.stdout.splitlines()]
    _, packets, _ = load_capture(path)
    assert len(rows) == sum(len(p) for p in packets.values())
    assert {r[0] for r in rows} == {str(tmp_path / "aoa"), str(tmp_path / "base")}
    assert {r[1] for r in rows} >= {"0", "1"}  # sent and received


async def test_capture_holds_the_bytes_seen_while_sniffing(tmp_path: Path) -> None:
    """Sniffing reads, and on a silent port writes AT, before the driver's port opens: the
    capture must still hold those bytes (they crossed the port)."""
    from rfhoming.host.session import open_drivers

    master, slave = os.openpty()
    os.set_blocking(master, False)
    loop = asyncio.get_running_loop()
    loop.call_later(0.5, os.write, master, b"\xfe\xfd sniffed noise")  # once the sniffer listens

    def answer() -> None:
        if b"AT\r" in os.read(master, 4096):
            os.write(master, b"\r\nOK\r\n")

    loop.add_reader(master, answer)
    writer = CaptureWriter(tmp_path / "sniff.pcapng")
    try:
        drivers = await open_drivers([os.ttyname(slave)], baud=115200, taps=[writer.tap], describe=writer.describe)
    finally:
        loop.remove_reader(master)
        writer.close()
        os.close(master)
        os.close(slave)
    assert [d.kind for d in drivers] == ["xplr-aoa"]
    interfaces, packets, torn = pcapng.read_all((tmp_path / "sniff.pcapng").read_bytes())
    assert [recorded_kind(i).name for i in interfaces] == ["xplr-aoa"] and torn == 0
    inbound = b"".join(p.data for p in packets if p.direction == pcapng.INBOUND)
    outbound = b"".join(p.data for p in packets if p.direction == pcapng.OUTBOUND)
    assert inbound == b"\xfe\xfd sniffed noise\r\nOK\r\n" and outbound == b"AT\r"
    assert [p.t for p in packets] == sorted(p.t for p in packets)


def test_capture_headers_are_on_disk_before_any_data(tmp_path: Path) -> None:
    """A capture killed right after set-up is readable: section and interface blocks are flushed
    (to c.pcapng.part, which a kill leaves; c.pcapng is as it was)."""
    writer = CaptureWriter(tmp_path / "c.pcapng")
    writer.describe("/dev/ttyACM0", kind="xplr-aoa")
    interfaces, packets, torn = pcapng.read_all(part_of(tmp_path / "c.pcapng").read_bytes())  # before close
    assert [i.name for i in interfaces] == ["/dev/ttyACM0"] and packets == [] and torn == 0
    writer.close()
