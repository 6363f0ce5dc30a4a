"""A Bluetooth LE controller behind an H4 UART (an nRF52840 or ESP32 in HCI-UART mode).

The command handling is bumble's own virtual controller (:class:`bumble.controller.Controller`):
it answers the whole HCI command set a host sends at start-up (reset, version, features,
buffer sizes, event masks ...) as a controller does, which a model written here would only
approximate. What bumble's controller lacks for a receiver model is added here:

- advertising reports come from the world, not from bumble's in-process link, with the radio
  model's RSSI (bumble reports a fixed -50 dBm) and the scan's limits: only inside the scan
  window, only on the channel of the current interval (37, 38, 39 in turn), not when two
  packets collide, not below the sensitivity;
- the scan interval and window the host set (bumble ignores the extended ones), and
  HCI_Reset stops scanning and restores the default event masks (bumble's Reset leaves both);
- the event masks gate the reports (LE Meta event bit 61, off by default; LE Advertising
  Report bit 1; LE Extended Advertising Report bit 12, off by default), so a host that forgets
  them hears nothing;
- duplicate filtering when the host enables it: one report per address per scan enable;
- reports are sent at once (bumble schedules them with ``call_soon``), so bytes follow the
  emulator's clock deterministically; the TX buffer is bounded (drops counted).

Sans-IO like the other models: :meth:`receive` (host bytes), :meth:`read`, :meth:`tick`,
:meth:`on_advertisement`. bumble's controller needs a running asyncio loop to exist, so it is
built on first use.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, cast

from bumble import hci
from bumble.controller import Controller
from rfhoming.firmware.ble_scan_radio import ScanRadio, listening_channel
from rfhoming.protocol.h4 import TO_CONTROLLER, H4Splitter

TX_BUFFER = 65536
SENSITIVITY_DBM = -97.0
UNIT_US = 625
LE_META_EVENT_BIT = 1 << 61
LE_ADV_REPORT_BIT, LE_EXT_ADV_REPORT_BIT = 1 << 1, 1 << 12
DEFAULT_EVENT_MASK, DEFAULT_LE_EVENT_MASK = 0x00001FFFFFFFFFFF, 0x1F  # Core v5.4 Vol 4 Part E 7.3.1, 7.8.1
DATA_COMPLETE, DATA_INCOMPLETE, DATA_TRUNCATED = 0, 1, 2
"""Extended report data status, event type bits 5-6 (Core v5.4 Vol 4 Part E 7.7.65.13)."""


class _ScanningController(Controller):
    """bumble's controller, scanning the way :class:`HciControllerFirmware` says."""

    def __init__(self, out: Any, address: str, fragment_bytes: int | None = None, truncate: bool = False) -> None:
        super().__init__("rfhoming-hci", public_address=hci.Address(address, hci.Address.PUBLIC_DEVICE_ADDRESS))
        self._out = out
        self.fragment_bytes = fragment_bytes
        self.truncate = truncate
        self.scan_interval = 16  # units of 0.625 ms: the spec's defaults (10 ms)
        self.scan_window = 16
        self.active = False
        self.extended = False
        self.reported: set[str] = set()
        self.event_mask, self.le_event_mask = DEFAULT_EVENT_MASK, DEFAULT_LE_EVENT_MASK  # as after a reset

    def send_hci_packet(self, packet: hci.HCI_Packet) -> None:
        self._out(bytes(packet))

    def on_hci_reset_command(self, command: hci.HCI_Reset_Command) -> Any:
        self.le_scan_enable = False
        self.event_mask, self.le_event_mask = DEFAULT_EVENT_MASK, DEFAULT_LE_EVENT_MASK
        return super().on_hci_reset_command(command)

    def on_hci_le_set_scan_parameters_command(self, command: hci.HCI_LE_Set_Scan_Parameters_Command) -> Any:
        result = super().on_hci_le_set_scan_parameters_command(command)
        if result.status == hci.HCI_SUCCESS:
            if not 4 <= command.le_scan_window <= command.le_scan_interval <= 0x4000:
                return hci.HCI_StatusReturnParameters(hci.HCI_ErrorCode.INVALID_COMMAND_PARAMETERS_ERROR)
            self.scan_interval, self.scan_window = command.le_scan_interval, command.le_scan_window
            self.active = bool(command.le_scan_type)
        return result

    def on_hci_le_set_extended_scan_parameters_command(
            self, command: hci.HCI_LE_Set_Extended_Scan_Parameters_Command) -> Any:
        if self.le_scan_enable or not command.scan_intervals:
            return hci.HCI_StatusReturnParameters(hci.HCI_ErrorCode.COMMAND_DISALLOWED_ERROR)
        interval, window = command.scan_intervals[0], command.scan_windows[0]
        if not 4 <= window <= interval:
            return hci.HCI_StatusReturnParameters(hci.HCI_ErrorCode.INVALID_COMMAND_PARAMETERS_ERROR)
        self.scan_interval, self.scan_window, self.active = interval, window, bool(command.scan_types[0])
        return super().on_hci_le_set_extended_scan_parameters_command(command)

    def on_hci_le_set_scan_enable_command(self, command: hci.HCI_LE_Set_Scan_Enable_Command) -> Any:
        self.extended, self.reported = False, set()
        return super().on_hci_le_set_scan_enable_command(command)

    def on_hci_le_set_extended_scan_enable_command(self, command: hci.HCI_LE_Set_Extended_Scan_Enable_Command) -> Any:
        self.extended, self.reported = True, set()
        return super().on_hci_le_set_extended_scan_enable_command(command)

    def report(self, address: str, addr_type: int, rssi: int, ad: bytes) -> str | None:
        """Send one report of a non-connectable advertisement; None, or why it was not sent."""
        if not self.event_mask & LE_META_EVENT_BIT:
            return "masked"
        if self.filter_duplicates and address in self.reported:
            return "duplicate"
        addr = hci.Address(address, cast(hci.AddressType, addr_type))  # any int the report's field carries
        if self.extended:
            if not self.le_event_mask & LE_EXT_ADV_REPORT_BIT:
                return "masked"
            Report = hci.HCI_LE_Extended_Advertising_Report_Event.Report
            legacy = hci.HCI_LE_Extended_Advertising_Report_Event.EventType.LEGACY_ADVERTISING_PDU_USED
            if self.fragment_bytes:  # extended PDUs: the data in fragments, by the data status bits
                chunks = [ad[i:i + self.fragment_bytes] for i in range(0, len(ad), self.fragment_bytes)] or [b""]
                if self.truncate and len(chunks) > 1:
                    chunks = chunks[:-1]
                statuses: Sequence[int | None] = [DATA_INCOMPLETE] * (len(chunks) - 1) + [DATA_TRUNCATED if self.truncate else DATA_COMPLETE]
            else:
                chunks, statuses = [ad], [None]
            for chunk, status in zip(chunks, statuses):
                event_type = legacy if status is None else status << 5
                self.send_hci_packet(hci.HCI_LE_Extended_Advertising_Report_Event([Report(
                    event_type=event_type, address_type=addr_type, address=addr, primary_phy=hci.Phy.LE_1M,
                    secondary_phy=0 if status is None else hci.Phy.LE_1M, advertising_sid=0xFF if status is None else 0,
                    tx_power=0x7F, rssi=rssi, periodic_advertising_interval=0, direct_address_type=0,
                    direct_address=hci.Address.ANY, data=chunk)]))
            self.reported.add(address)
            return None
        else:
            if not self.le_event_mask & LE_ADV_REPORT_BIT:
                return "masked"
            event = hci.HCI_LE_Advertising_Report_Event([hci.HCI_LE_Advertising_Report_Event.Report(
                event_type=hci.HCI_LE_Advertising_Report_Event.EventType.ADV_NONCONN_IND,
                address_type=addr_type, address=addr, data=ad, rssi=rssi)])
        self.reported.add(address)
        self.send_hci_packet(event)
        return None


class HciControllerFirmware:
    """The controller model with its H4 UART and its radio."""

    def __init__(self, address: str = "C0:FF:EE:00:00:01", *, fragment_bytes: int | None = None,
                 truncate: bool = False) -> None:
        """``fragment_bytes``: extended reports carry the data in fragments of this size (a BT5
        controller fragments what does not fit one event); ``truncate``: the last fragment is
        lost and the report ends "truncated"."""
        self.address = address
        self.fragment_bytes, self.truncate = fragment_bytes, truncate
        self.counters = {"tx_dropped": 0, "rx_errors": 0, "reported": 0, "duty_cycle": 0, "wrong_channel": 0,
                         "collision": 0, "below_sensitivity": 0, "masked": 0, "duplicate": 0}
        self._out = bytearray()
        self._splitter = H4Splitter(TO_CONTROLLER)
        self._controller: _ScanningController | None = None
        self.radio = ScanRadio()

    @property
    def controller(self) -> _ScanningController:
        if self._controller is None:
            self._controller = _ScanningController(self._write, self.address, self.fragment_bytes, self.truncate)
        return self._controller

    def _write(self, data: bytes) -> None:
        if len(self._out) + len(data) > TX_BUFFER:
            self.counters["tx_dropped"] += 1
            return
        self._out += data

    def read(self) -> bytes:
        data = bytes(self._out)
        self._out.clear()
        return data

    def receive(self, data: bytes) -> None:
        """Host bytes: every whole command packet goes to the controller; the rest is counted."""
        for item in self._splitter.feed(data):
            if not isinstance(item, bytes) or item[0] != 0x01:
                self.counters["rx_errors"] += 1
                continue
            try:
                packet = hci.HCI_Packet.from_bytes(item)
            except Exception:  # bumble raises several types for a malformed command  # noqa: BLE001
                self.counters["rx_errors"] += 1
                continue
            self.controller.on_hci_packet(packet)

    def tick(self, now_us: int) -> None:
        """Nothing is timed inside the controller model; the clock only gates the radio."""

    def listening_channel(self, t_us: int) -> int | None:
        c = self.controller
        return listening_channel(t_us, c.le_scan_enable, c.scan_interval * UNIT_US, c.scan_window * UNIT_US)

    def on_advertisement(self, t_us: int, channel: int, address: str, rssi_dbm: float, ad: bytes,
                         addr_type: int = 0) -> None:
        """One non-connectable advertisement at the antenna; ``address`` as AA:BB:CC:DD:EE:FF."""
        reason = self.radio.loss(t_us, channel, len(ad), rssi_dbm, self.listening_channel(t_us), SENSITIVITY_DBM)
        if reason is None:
            reason = self.controller.report(address, addr_type, max(-127, min(20, round(rssi_dbm))), ad)
        self.counters[reason or "reported"] += 1
