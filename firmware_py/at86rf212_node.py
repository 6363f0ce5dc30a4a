"""STM32 + four AT86RF212B receivers behind parabolic dishes (S2's directional RSS node).

Antennas 0..3 are x1, x2, y1, y2: x1 looks along the robot heading, x2 backwards, y1 to the
left, y2 to the right (pairs 180° apart, pairs 90° apart). Each dish has a Gaussian main lobe
with half-power beam width θ3 = 70 λ / d degrees and a floor at the front/back ratio. Each chip
measures the frame it received with its own offset (±5 dB absolute accuracy) and quantises it
to ED 0..84 above RSSI_BASE_VAL; a frame below sensitivity is not received at all.
Output: 0x02 per antenna that received the frame, then one 0x03 for the set.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

from rfhoming.protocol.at86rf212 import dbm_to_ed, rssi_base_dbm
from rfhoming.firmware.framed_node import FramedNode
from rfhoming.protocol.frames import AntennaReading, AntennaSet, NodeCommand, RfFrame

WAVELENGTH_M = 0.3276
BORESIGHT_RAD = (0.0, math.pi, math.pi / 2, -math.pi / 2)
TRX_CTRL_2 = 0x24  # BPSK-40 defaults
RX_STATUS_CRC_OK = 0x80


def beam_width_deg(dish_diameter_m: float) -> float:
    """Half-power beam width of a parabolic dish: θ3 ≈ 70 λ / d."""
    return 70.0 * WAVELENGTH_M / dish_diameter_m


def dish_gain_db(off_axis_rad: float, dish_diameter_m: float, front_back_db: float,
                 efficiency: float = 0.55) -> float:
    """Gain relative to isotropic at ``off_axis_rad`` from boresight."""
    peak = 10 * math.log10(efficiency * (math.pi * dish_diameter_m / WAVELENGTH_M) ** 2)
    off = math.degrees(abs(math.remainder(off_axis_rad, 2 * math.pi)))
    lobe = -12.0 * (off / beam_width_deg(dish_diameter_m)) ** 2
    return peak + max(lobe, -front_back_db)


class At86rf212NodeFirmware(FramedNode):
    DEVICE_KIND = 2

    def __init__(self, node_id: int, *, dish_diameter_m: float = 0.3, front_back_db: float = 20.0,
                 channel: int = 1, page: int = 0, chip_offsets_db: Sequence[float] = (0, 0, 0, 0),
                 sensitivity_dbm: float = -110.0, ed_scale_db: float = 1.0) -> None:
        if any(abs(o) > 5 for o in chip_offsets_db) or len(chip_offsets_db) != 4:
            raise ValueError("four chip offsets within ±5 dB")
        super().__init__(node_id)
        self.dish_diameter_m = dish_diameter_m
        self.front_back_db = front_back_db
        self.chip_offsets_db = tuple(chip_offsets_db)
        self.sensitivity_dbm = sensitivity_dbm
        self.ed_scale_db = ed_scale_db
        self.set_channel(channel, page)
        self.receiving = True
        self.counters.update(frames=0, lost=0)

    def set_channel(self, channel: int, page: int) -> None:
        self.base_dbm = rssi_base_dbm(page, channel)  # ValueError for an unknown PHY mode
        self.channel, self.page = channel, page

    def antenna_gains_db(self, bearing_rad: float) -> list[float]:
        """Gain of each antenna for a source at ``bearing_rad`` (robot frame, CCW)."""
        return [dish_gain_db(bearing_rad - b, self.dish_diameter_m, self.front_back_db)
                for b in BORESIGHT_RAD]

    def on_frame(self, t_us: int, emitter_seq: int, bearing_rad: float,
                 incident_dbm: Sequence[float], psdu: bytes = b"") -> None:
        """One emitter frame; ``incident_dbm[i]`` is the power an isotropic antenna i would see."""
        if not self.receiving:
            return
        gains = self.antenna_gains_db(bearing_rad)
        self._receive(t_us, emitter_seq, [incident_dbm[i] + gains[i] for i in range(4)], psdu)

    def on_paths(self, t_us: int, emitter_seq: int, paths: Sequence[tuple[float, float]],
                 noise_db: Sequence[float], psdu: bytes = b"") -> None:
        """One emitter frame over several paths, each (bearing_rad, incident dBm): each dish
        weights each path by its own gain toward that path's arrival and sums the powers, so
        behind a wall the dish facing a reflection can be the strongest; ``noise_db[i]`` is
        dish i's fading and bias, added after the sum."""
        if not self.receiving:
            return
        powers = [p + n for p, n in zip(self.dish_powers(paths), noise_db)]
        self._receive(t_us, emitter_seq, powers, psdu)

    def dish_powers(self, paths: Sequence[tuple[float, float]]) -> list[float]:
        """Each dish's power (dBm) from paths (bearing_rad, incident dBm): gain-weighted power sum."""
        peak = dish_gain_db(0.0, self.dish_diameter_m, self.front_back_db)
        k = 12.0 / beam_width_deg(self.dish_diameter_m) ** 2
        out = []
        for boresight in BORESIGHT_RAD:  # dish_gain_db inlined: this runs for every path of every frame
            total = 0.0
            for b, p in paths:
                off = math.degrees(math.remainder(b - boresight, 2 * math.pi))
                total += 10 ** ((p + peak + max(-k * off * off, -self.front_back_db)) / 10)
            out.append(10 * math.log10(total))
        return out

    def _receive(self, t_us: int, emitter_seq: int, powers: list[float], psdu: bytes) -> None:
        """Each chip measures its dish's power (dBm at the chip's input)."""
        readings, mask = [], 0
        for i in range(4):
            power = powers[i]
            if power < self.sensitivity_dbm:
                readings.append(AntennaReading(255, 0, 0))
                continue
            measured = power + self.chip_offsets_db[i]
            ed = dbm_to_ed(measured, self.base_dbm, self.ed_scale_db)
            lqi = 255 if power > self.sensitivity_dbm + 10 else int(255 * (power - self.sensitivity_dbm) / 10)
            dt_us = 3 * i  # the four chips timestamp a few µs apart
            readings.append(AntennaReading(ed, lqi, dt_us))
            mask |= 1 << i
            self.send(RfFrame(self.node_id, self.next_seq(), (t_us + dt_us) & 0xFFFFFFFF, i,
                               self.channel, self.page, TRX_CTRL_2, self.base_dbm, ed, lqi,
                               RX_STATUS_CRC_OK, emitter_seq & 0xFFFF, psdu))
        if not mask:
            self.counters["lost"] += 1
            return
        self.counters["frames"] += 1
        self.send(AntennaSet(self.node_id, self.next_seq(), t_us & 0xFFFFFFFF, emitter_seq & 0xFFFF,
                              self.channel, self.page, self.base_dbm, mask, tuple(readings)))

    def command(self, cmd: NodeCommand) -> None:
        """0x80: 1 set channel/page (<BB), 2 start, 3 stop, 4 request status."""
        if cmd.command == 1 and len(cmd.args) == 2:
            try:
                self.set_channel(cmd.args[0], cmd.args[1])
            except ValueError as exc:
                self.log(str(exc))
        elif cmd.command in (2, 3):
            self.receiving = cmd.command == 2
        elif cmd.command == 4:
            self.send_status()
        else:
            self.log(f"bad command {cmd.command} with {len(cmd.args)} arg bytes")
