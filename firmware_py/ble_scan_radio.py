"""What every BLE scanner model shares: the radio in front of its controller.

A scanner listens during ``window`` of every ``interval``, hopping 37 -> 38 -> 39 per interval
(Bluetooth Core, Vol 6 Part B 4.4.3); a packet is heard only if it arrives inside the window, on
the channel being listened to, not overlapping an earlier packet on that channel, and above the
receiver's sensitivity. The ESP32 scanner, the ESP-AT board and the HCI controller models all
decide it here, so they lose packets alike.
"""

from __future__ import annotations

AIR_US_PER_BYTE = 8  # LE 1M PHY: 1 µs a bit
OVERHEAD_BYTES = 16  # preamble, access address, header, advertiser address, CRC
LOSSES = ("duty_cycle", "wrong_channel", "collision", "below_sensitivity")


def listening_channel(t_us: int, scanning: bool, interval_us: int, window_us: int) -> int | None:
    """The advertising channel listened to at ``t_us``, None outside the scan window."""
    if not scanning or t_us % interval_us >= window_us:
        return None
    return 37 + (t_us // interval_us) % 3


class ScanRadio:
    """Tracks each channel's air time, so that overlapping packets collide."""

    def __init__(self) -> None:
        self._last_end_us = {37: -1, 38: -1, 39: -1}

    def loss(self, t_us: int, channel: int, ad_len: int, rssi_dbm: float, listening: int | None,
             sensitivity_dbm: float) -> str | None:
        """Why a packet on the air at ``t_us`` is not heard (one of LOSSES), or None."""
        end = t_us + (ad_len + OVERHEAD_BYTES) * AIR_US_PER_BYTE
        collided = t_us < self._last_end_us.get(channel, -1)
        self._last_end_us[channel] = max(end, self._last_end_us.get(channel, -1))
        if listening is None:
            return "duty_cycle"
        if listening != channel:
            return "wrong_channel"
        if collided:
            return "collision"
        if rssi_dbm < sensitivity_dbm:
            return "below_sensitivity"
        return None
