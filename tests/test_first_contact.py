"""Devices at first contact: what the board remembers, when a set-up deadline starts, what a
receiver that never answers (or answers and hears nothing) says, against the emulated boards."""

from __future__ import annotations

import asyncio
from pathlib import Path
from typing import Any

import pytest

from rfhoming.emulator.runtime import Emulator
from rfhoming.emulator.scenario import load
from rfhoming.host import portspec
from rfhoming.host.drivers.aoa import AoaDriver, AoaSetup
from rfhoming.host.drivers.common import Driver
from rfhoming.host.ports import HostPort
from rfhoming.host.supervise import DeviceNotReady, supervise

TAG = "CCF9578E0D8A"  # s0-open's tag
OTHER = "000000000000"


async def start(tmp_path: Path, scenario: str = "s0-open", *, receiver: str | None = None,
                options: dict[str, Any] | None = None) -> Emulator:
    sc = load(scenario, seed=3, receiver=receiver) if receiver else load(scenario, seed=3)
    for device in sc.devices:
        device.options.update((options or {}).get(device.name, {}))
    em = Emulator(sc, transport="pty", seed=3, speed=4.0, link_dir=tmp_path)
    await em.start()
    em.task = asyncio.create_task(em.run())
    return em


async def stop(em: Emulator, *tasks: asyncio.Task) -> None:
    for task in (*tasks, em.task):
        task.cancel()
        await asyncio.gather(task, return_exceptions=True)
    await em.close()


def where(em: Emulator, device: str) -> str:
    endpoint = em.device(device).link.describe()
    return endpoint.get("path") or endpoint["url"]


async def until(predicate: Any, timeout: float = 15.0) -> None:
    """A hang guard, not a speed requirement."""
    async with asyncio.timeout(timeout):
        while not predicate():
            await asyncio.sleep(0.02)


def stored_filter(em: Emulator, ids: list[str]) -> None:
    """The board as an earlier ``tags=`` left it: the filter stored (AT&W) and in effect."""
    fw = em.device("aoa").firmware
    for settings in (fw.saved, fw.active, fw.pending):
        settings.filters[2] = list(ids)


# -- 1. the tag filter stored on the board --------------------------------------------------
async def test_a_stored_tag_filter_is_read_reported_and_named_by_the_silence_hint(tmp_path: Path) -> None:
    em = await start(tmp_path)
    stored_filter(em, [OTHER])  # tags= of an absent tag, stored by an earlier run
    driver = AoaDriver(HostPort(where(em, "aoa")), AoaSetup(silence_timeout=1.0))  # no tags= this time
    task = asyncio.create_task(driver.run())
    await until(lambda: driver.counters["silent"] == 1)
    assert driver.board_filter == (OTHER,) and driver.health()["board_filter"] == OTHER
    assert "stored tag filter" in driver.problem and OTHER in driver.problem and "tags=none" in driver.problem
    assert em.device("aoa").firmware.saved.filters[2] == [OTHER]  # reported, not changed unasked
    await stop(em, task)


async def test_tags_none_clears_the_stored_filter(tmp_path: Path) -> None:
    em = await start(tmp_path)
    stored_filter(em, [OTHER])
    spec = portspec.parse(f"xplr-aoa:{where(em, 'aoa')},tags=none")
    assert str(spec).endswith(",tags=none")
    driver = AoaDriver.from_spec(spec, [])
    task = asyncio.create_task(driver.run())
    await until(lambda: driver.state == "streaming")
    assert driver.board_filter == () and driver.health()["board_filter"] == ""
    assert em.device("aoa").firmware.saved.filters[2] == [] and driver.counters["restarts"] == 1
    assert (await asyncio.wait_for(driver.out.get(), 15)).tag == TAG
    await stop(em, task)


# -- the set-up deadline starts at first contact --------------------------------------------
class _Clock:
    def __init__(self) -> None:
        self.now = 0.0

    def __call__(self) -> float:
        return self.now


class _QuietPort:
    name = "slow"
    counters = {"bytes_in": 0}


class _SetsUp(Driver):
    kind = "xplr-aoa"
    sets_up = True


async def test_the_set_up_deadline_counts_from_the_first_answer_not_from_the_start() -> None:
    """A machine so loaded that the device's port opens, and its first bytes come, late: the
    deadline (1 s here) restarts at the open, then at the first bytes. Driven by a fake clock:
    nothing here depends on how fast this machine is."""
    clock = _Clock()
    driver = _SetsUp(_QuietPort())  # type: ignore[arg-type]
    driver.contact_clock = clock
    driver.state = "opening"
    watch = asyncio.create_task(supervise({driver: 1.0}, clock=clock, period=0))

    async def at(t: float) -> None:
        clock.now = t
        for _ in range(5):
            await asyncio.sleep(0)
        assert not watch.done(), watch

    await at(0.9)  # a loaded machine: the port opens 0.9 s after the start
    driver.opened_at, driver.state = 0.9, "setting_up"
    await at(1.8)  # 0.9 s after the open, silent: within the deadline (timed from the start: past it)
    driver.answered_at = _QuietPort.counters["bytes_in"] = 1.8  # the first bytes
    await at(2.7)  # 0.9 s after them: still within the deadline
    clock.now = 2.9  # 1.1 s after them: not ready
    with pytest.raises(DeviceNotReady, match="slow .xplr-aoa. was not ready within 1 s of its first answer"):
        await asyncio.wait_for(watch, 5)


async def test_a_port_silent_since_its_open_ends_at_its_deadline_and_says_so() -> None:
    clock = _Clock()
    driver = _SetsUp(_SilentPort())  # type: ignore[arg-type]
    driver.contact_clock = clock
    driver.opened_at, driver.state = 0.0, "setting_up"
    watch = asyncio.create_task(supervise({driver: 1.0}, clock=clock, period=0))
    clock.now = 1.1
    with pytest.raises(DeviceNotReady, match="said nothing within 1 s of its port opening"):
        await asyncio.wait_for(watch, 5)


class _SilentPort:
    name = "silent"
    counters = {"bytes_in": 0}


# -- 3. a receiver set up but hearing nothing -----------------------------------------------
@pytest.mark.parametrize("kind", ["esp-at", "hci"])
async def test_a_receiver_that_hears_nothing_says_so(tmp_path: Path, kind: str) -> None:
    from rfhoming.host.drivers.espat import EspAtDriver, EspAtSetup
    from rfhoming.host.drivers.hci import HciDriver, HciSetup

    em = await start(tmp_path, "s3-arena", receiver=kind)
    em.device("ble").firmware.on_advertisement = lambda *args, **kw: None  # no advertiser in range
    port = HostPort(where(em, "ble"), baud=115200 if kind == "esp-at" else 1_000_000)
    driver = EspAtDriver(port, EspAtSetup(silence_timeout=1.0)) if kind == "esp-at" \
        else HciDriver(port, HciSetup(silence_timeout=1.0))
    task = asyncio.create_task(driver.run())
    await until(lambda: driver.counters["silent"] == 1)
    assert driver.state == "streaming" and "although it is set up" in driver.health()["problem"]
    assert "no Bluetooth LE advertiser in range" in driver.problem
    await stop(em, task)


# -- 4. binary output: explained once, then counted -----------------------------------------
async def test_binary_output_is_explained_once_then_counted_quietly(tmp_path: Path) -> None:
    em = await start(tmp_path, options={"aoa": {"dialect": "embed"}})
    fw = em.device("aoa").firmware
    fw.saved.udfcfg[7] = fw.active.udfcfg[7] = fw.pending.udfcfg[7] = 2
    driver = AoaDriver(HostPort(where(em, "aoa")))  # the default garbage timeout: 3 s of drops before
    shown: list[tuple[int, Any]] = []  # (explained yet, item)
    driver.listeners.append(lambda name, t, item: shown.append((driver.counters["binary_output"], item)))
    task = asyncio.create_task(driver.run())
    await until(lambda: driver.counters["binary_events"] >= 30)
    before = [item for explained, item in shown if item.kind == "drop" and not explained]
    after = [item for explained, item in shown if item.kind == "drop" and explained]
    assert driver.counters["binary_output"] == 1 and not after and len(before) <= 10, (len(before), len(after))
    counted = sum(v for k, v in driver.decoder.counters.items() if k.startswith("drop"))
    assert counted > len(before) + 20  # the frames since are counted, not shown
    await stop(em, task)


# -- 6. USB dongles: what libusb says, turned into what to do -------------------------------
@pytest.mark.parametrize(("error", "says"), [
    ("USBErrorOther", "held by another driver"), ("USBErrorBusy", "held by another driver"),
    ("USBErrorAccess", "udev rule"), ("USBErrorNoDevice", "plugged in")])
async def test_libusb_errors_say_what_to_do(monkeypatch: pytest.MonkeyPatch, error: str, says: str) -> None:
    usb1 = pytest.importorskip("usb1")
    import bumble.transport

    from rfhoming.host.drivers.hci import BumbleTransportPort
    from rfhoming.host.ports import PortError

    async def refuse(name: str) -> None:
        raise getattr(usb1, error)()

    monkeypatch.setattr(bumble.transport, "open_transport", refuse)
    with pytest.raises(PortError) as caught:
        await BumbleTransportPort("usb:0").open()
    message = str(caught.value)
    assert says in message and "usb:0" in message and "\n" not in message and "LIBUSB_ERROR" in message


async def test_a_realtek_dongle_is_told_how_to_get_its_firmware(monkeypatch: pytest.MonkeyPatch) -> None:
    import bumble.transport

    from rfhoming.host.drivers.hci import BumbleTransportPort

    class _Source:
        metadata = {"vendor_id": 0x0BDA, "product_id": 0x8771}  # an RTL8761B dongle

        def set_packet_sink(self, sink: Any) -> None:
            pass

    class _Transport:
        source, sink = _Source(), None

        async def close(self) -> None:
            pass

    async def opened(name: str) -> _Transport:
        return _Transport()

    monkeypatch.setattr(bumble.transport, "open_transport", opened)
    port = BumbleTransportPort("usb:0")
    await port.open()
    hint = port.firmware_hint or ""
    for needed in ("Realtek", "bumble-rtk-fw-download", "BUMBLE_RTK_FIRMWARE_DIR", "/lib/firmware/rtl_bt",
                   "bumble-rtk-util load usb:0"):
        assert needed in hint, hint
    await port.close()


# -- 7. an FTDI port is an XPLR-AOA only if it answers as one -------------------------------
@pytest.mark.slow  # 3 s of asking; the full suite keeps it
async def test_discovery_asks_an_ftdi_port_what_it_is(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    from serial.tools import list_ports_common

    from rfhoming.host import discovery

    (tmp_path / "aoa").mkdir()
    (tmp_path / "ble").mkdir()
    aoa_em = await start(tmp_path / "aoa", options={"aoa": {"dialect": "1.2"}})
    ble_em = await start(tmp_path / "ble", "s3-arena", receiver="esp-at")
    ports = []
    for em, device in ((aoa_em, "aoa"), (ble_em, "ble")):
        info = list_ports_common.ListPortInfo(where(em, device))
        info.vid, info.pid = 0x0403, 0x6015  # both behind FTDI bridges
        ports.append(info)
    monkeypatch.setattr(discovery.list_ports, "comports", lambda: ports)
    found = {c.device: c for c in await asyncio.to_thread(discovery.candidates)}
    assert found[where(aoa_em, "aoa")].kind == "xplr-aoa"
    other = found[where(ble_em, "ble")]
    assert other.kind is None and "does not answer as an XPLR-AOA" in other.reason and "esp-at:" in other.reason
    assert await asyncio.to_thread(discovery.resolve_auto, "xplr-aoa") == where(aoa_em, "aoa")
    await stop(aoa_em)
    await stop(ble_em)


# -- identification strings the driver did not expect ---------------------------------------
@pytest.mark.parametrize("model", ['"NINA-B4-DF-TAG"', "XPLR-AOA rev C, made-up", '"NINA-B411-40B"', "NINA-B411-40B"])
async def test_an_unexpected_identification_costs_only_the_guess(tmp_path: Path, model: str) -> None:
    """Whatever AT+GMM answers, quoted or not, the set-up goes on; the dialect is the guess (1.2)
    until the field count of a +UUDF line says otherwise -- never 1.0 for a name that merely
    starts like 1.0's."""
    em = await start(tmp_path, options={"aoa": {"dialect": "2.x"}})
    fw = em.device("aoa").firmware
    execute = fw._execute
    fw._execute = lambda line: fw._answer([model]) if line == "AT+GMM" else execute(line)
    driver = AoaDriver(HostPort(where(em, "aoa")))
    task = asyncio.create_task(driver.run())
    await until(lambda: driver.state == "streaming")
    assert driver.identity["model"] == model
    await asyncio.wait_for(driver.out.get(), 15)
    assert driver.dialect.value == "2.x"  # 10 fields decided
    await stop(em, task)


# -- ESP-AT: a board left in the server role ------------------------------------------------
async def test_an_esp_at_server_is_restarted_not_deinitialised(tmp_path: Path) -> None:
    """ESP-AT 3.2 changes a role only after AT+RST (master also allows AT+BLEINIT=0 first)."""
    from rfhoming.firmware.esp_at import EspAtFirmware
    from rfhoming.host.drivers.espat import EspAtDriver

    fw = EspAtFirmware("3.2")
    fw.receive(b"AT+BLEINIT=2\r\n")
    fw.read()
    sent: list[str] = []

    class _Wire:
        name, counters = "esp-at", {"bytes_in": 0}

        def write(self, data: bytes) -> None:
            sent.append(data.decode().strip())
            fw.receive(data)

    driver = EspAtDriver(_Wire())  # type: ignore[arg-type]

    async def pump() -> None:
        while True:
            driver.on_chunk(fw.read(), 0.0)
            await asyncio.sleep(0.001)

    feeding = asyncio.create_task(pump())
    try:
        await asyncio.wait_for(driver._set_up(), 15)
    finally:
        feeding.cancel()
    assert "AT+RST" in sent and "AT+BLEINIT=0" not in sent and fw.role == 1 and fw.scanning
    fresh = EspAtFirmware("3.2")
    for line in (b"AT+BLEINIT=2\r\n", b"AT+BLEINIT=0\r\n", b"AT+BLEINIT=1\r\n"):
        fresh.receive(line)
    assert fresh.read().endswith(b"ERROR\r\n") and fresh.role == 0  # the emulated 3.2 follows its docs
