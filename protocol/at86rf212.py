"""AT86RF212(B) energy detection (ED) -> dBm, keyed by PHY mode (docs/protocol.md §3, after the AT86RF212B datasheet).

Each received frame carries an ED byte: 0..84, about 1 dB a step above RSSI_BASE_VAL, which
depends on the PHY mode (page, channel). ED 0 means "at or below the base"; 255 means "no
measurement". The step (``scale``) is a calibration constant: datasheet-derived 1.03,
open-source drivers 1.0. (The 5-bit PHY_RSSI register, 0..28 in about 3.1 dB steps, is coarser;
rfhoming uses the per-frame ED.)
"""

from __future__ import annotations

ED_MAX = 84
ED_INVALID = 255
DEFAULT_SCALE_DB = 1.0

# (page, first channel, last channel) -> RSSI_BASE_VAL dBm. Sources differ by about 1 dB;
# these are the values of the current datasheet, and every node reports what it used.
_BASE_TABLE: tuple[tuple[int, int, int, int, str], ...] = (
    (0, 0, 0, -100, "BPSK-20, 868.3 MHz"),
    (0, 1, 10, -99, "BPSK-40, 915 MHz band"),
    (2, 0, 0, -98, "O-QPSK-100, 868.3 MHz"),
    (2, 1, 10, -98, "O-QPSK-250 (SIN), 915 MHz band"),
    (5, 0, 10, -97, "O-QPSK-250 (RC)"),
)


def rssi_base_dbm(page: int, channel: int) -> int:
    """RSSI_BASE_VAL for a PHY mode; ValueError names the supported modes otherwise."""
    for tpage, first, last, base, _name in _BASE_TABLE:
        if page == tpage and first <= channel <= last:
            return base
    modes = ", ".join(f"page {p} ch {a}-{b} ({n})" for p, a, b, _, n in _BASE_TABLE)
    raise ValueError(f"no RSSI_BASE_VAL for page {page} channel {channel}; known: {modes}")


def ed_to_dbm(ed: int, base_dbm: int, scale_db: float = DEFAULT_SCALE_DB) -> float | None:
    """Received power for one frame; None for ED 255 (no measurement).

    ED 0 returns the base itself: the true power is at or below it.
    """
    if ed == ED_INVALID:
        return None
    if not 0 <= ed <= ED_MAX:
        raise ValueError(f"ED {ed} outside 0..{ED_MAX} (255 = no measurement)")
    return base_dbm + scale_db * ed


def dbm_to_ed(power_dbm: float, base_dbm: int, scale_db: float = DEFAULT_SCALE_DB) -> int:
    """What the chip reports for a power: rounded to a step and saturated to 0..84."""
    ed = round((power_dbm - base_dbm) / scale_db)
    return min(max(ed, 0), ED_MAX)


def channel_frequency_mhz(channel: int) -> float:
    """Centre frequency: channel 0 is 868.3 MHz, channels 1..10 are 906 + 2(k-1) MHz."""
    if channel == 0:
        return 868.3
    if 1 <= channel <= 10:
        return 906.0 + 2.0 * (channel - 1)
    raise ValueError(f"channel {channel} outside 0..10")
