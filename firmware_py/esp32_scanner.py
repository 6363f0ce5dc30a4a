"""ESP32 BLE scanner node: scan duty cycle, channel hopping, collisions, int8 RSSI.

Sans-IO. The emulator calls :meth:`on_advertisement` for every advertisement that reaches the
antenna (with its channel and float received power); the firmware keeps what a real
controller would report: only while the scan window is open, only on the channel it is
listening to this interval, not when two packets overlap on that channel, not below the
sensitivity floor. Output: record 0x01 per report, status 0x10 at 1 Hz, log text 0x7F.

It scans all the time by default, as ESP-IDF's and the HCI's scan parameters default to
(docs/protocol.md, "The ESP32 scanner node"): a duty-cycled scan aliases with beacons
advertising near its interval and leaves each of them unheard for a second or more, which
no source says rfhoming's node does -- it is the emulator's fault option ``scan_window_ms``.
"""

from __future__ import annotations

from dataclasses import dataclass

from rfhoming.firmware.ble_scan_radio import ScanRadio, listening_channel
from rfhoming.firmware.framed_node import FramedNode
from rfhoming.protocol.frames import AdvReport, NodeCommand


@dataclass(frozen=True)
class ScanConfig:
    """ESP-IDF's ``esp_ble_scan_params_t`` defaults: interval = window = 0x0010 (10 ms)."""

    interval_us: int = 10_000  # 0.625 ms units on the chip: 16 units
    window_us: int = 10_000
    sensitivity_dbm: float = -97.0


class Esp32ScannerFirmware(FramedNode):
    DEVICE_KIND = 1

    def __init__(self, node_id: int, config: ScanConfig = ScanConfig()) -> None:
        super().__init__(node_id)
        if not 2_500 <= config.window_us <= config.interval_us <= 10_240_000:
            raise ValueError("need 2.5 ms <= scan window <= scan interval <= 10.24 s")
        self.config = config
        self.scanning = True
        self.counters.update(reported=0, duty_cycle=0, wrong_channel=0, collision=0, below_sensitivity=0)
        self.radio = ScanRadio()

    def listening_channel(self, t_us: int) -> int | None:
        """The channel the controller listens on at ``t_us``, None outside the window."""
        return listening_channel(t_us, self.scanning, self.config.interval_us, self.config.window_us)

    def on_advertisement(self, t_us: int, channel: int, addr: bytes, rssi_dbm: float,
                         ad: bytes, tx_power_dbm: int = 127, addr_type: int = 0,
                         adv_props: int = 0x13) -> None:
        """One packet on the air arriving at the antenna at ``t_us``."""
        reason = self.radio.loss(t_us, channel, len(ad), rssi_dbm, self.listening_channel(t_us),
                                 self.config.sensitivity_dbm)
        if reason is not None:
            self.counters[reason] += 1
            return
        rssi = max(-127, min(20, round(rssi_dbm)))
        self.send(AdvReport(self.node_id, self.next_seq(), t_us & 0xFFFFFFFF, addr, addr_type,
                             adv_props, rssi, tx_power_dbm, 255, ad))
        self.counters["reported"] += 1

    def command(self, cmd: NodeCommand) -> None:
        """0x80: 2 start scanning, 3 stop, 4 request status."""
        if cmd.command in (2, 3):
            self.scanning = cmd.command == 2
        elif cmd.command == 4:
            self.send_status()
        else:
            self.log(f"unknown command {cmd.command}")
