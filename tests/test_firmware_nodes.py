"""ESP32 scanner, AT86RF212 node and robot base, spoken to through the binary framing."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from rfhoming.firmware.at86rf212_node import At86rf212NodeFirmware, beam_width_deg, dish_gain_db
from rfhoming.firmware.esp32_scanner import Esp32ScannerFirmware, ScanConfig
from rfhoming.firmware.robot_base import BaseLimits, RobotBaseFirmware, Slip
from rfhoming.protocol.at86rf212 import ed_to_dbm
from rfhoming.protocol.frames import AntennaSet, FrameDecoder, NodeCommand, Odometry, RfFrame, VelocityCommand, encode_frame


def records(fw) -> list:
    out = FrameDecoder().feed(fw.read())
    assert all(r.kind != "drop" for r in out)
    return out


# -- ESP32 --------------------------------------------------------------------------------
def test_esp32_status_every_second_and_reports() -> None:
    fw = Esp32ScannerFirmware(4)
    for t in range(0, 3_000_001, 10_000):
        fw.tick(t)
    assert [r.kind for r in records(fw)] == ["status"] * 4
    fw.on_advertisement(1000, 37, b"\x01" * 6, -61.6, b"\x02\x01\x06")
    (report,) = records(fw)
    assert (report.rssi_dbm, report.channel, report.node_id) == (-62, 255, 4)


def test_esp32_duty_cycle_channel_hop_collision_sensitivity() -> None:
    fw = Esp32ScannerFirmware(1, ScanConfig(interval_us=100_000, window_us=50_000, sensitivity_dbm=-90))
    fw.on_advertisement(60_000, 37, b"\x01" * 6, -50, b"")  # window closed
    fw.on_advertisement(110_000, 37, b"\x01" * 6, -50, b"")  # listening on 38 now
    fw.on_advertisement(110_000, 38, b"\x01" * 6, -95, b"")  # below sensitivity
    fw.on_advertisement(120_000, 38, b"\x01" * 6, -50, b"")
    fw.on_advertisement(120_100, 38, b"\x02" * 6, -50, b"")  # overlaps the previous packet
    c = fw.counters
    assert (c["duty_cycle"], c["wrong_channel"], c["below_sensitivity"], c["collision"], c["reported"]) == (1, 1, 1, 1, 1)


def test_esp32_stop_start_and_status_commands() -> None:
    fw = Esp32ScannerFirmware(1)
    fw.receive(encode_frame(NodeCommand(0, 1, 0, 3, b"")))
    fw.on_advertisement(1000, 37, b"\x01" * 6, -50, b"")
    fw.receive(encode_frame(NodeCommand(0, 2, 0, 4, b"")) + b"\x00garbage\x00")
    assert [r.kind for r in records(fw)] == ["status"]
    assert fw.counters["rx_errors"] == 1 and fw.counters["reported"] == 0


def beacon_silences(config: ScanConfig, seconds: float = 30.0, beacons: int = 4, seed: int = 1) -> tuple[float, float]:
    """Beacons advertising every 100 ms plus the advertiser's random 0-10 ms delay (Core Spec
    Vol 6 Part B 4.4.2.2.1), each event on 37, 38, 39, heard by the scanner: the longest time
    one beacon goes unreported, and all of them together (s)."""
    rng = np.random.default_rng(seed)
    events = []
    for b in range(beacons):
        t = float(rng.uniform(0, 0.1))
        while t < seconds:
            events.append((t, b))
            t += 0.1 + float(rng.uniform(0, 0.01))
    fw, decoder, heard = Esp32ScannerFirmware(1, config), FrameDecoder(), []
    for t, b in sorted(events):
        for k, channel in enumerate((37, 38, 39)):
            fw.on_advertisement(int(t * 1e6) + 400 * k, channel, bytes([b]) * 6, -80.0, b"\x02\x01\x06")
        heard += [(r.t_us / 1e6, r.addr) for r in decoder.feed(fw.read()) if r.kind == "adv_report"]
    per_beacon = max(float(np.diff([t for t, a in heard if a == addr]).max()) for addr in {a for _, a in heard})
    return per_beacon, float(np.diff([t for t, _ in heard]).max())


def test_esp32_scans_all_the_time_so_no_beacon_goes_unheard_for_long() -> None:
    """The default scan is continuous (ESP-IDF's defaults): every beacon is heard at its own
    rate, nothing goes unreported for longer than the homing loop's 0.3 s stale bound. A 50 %
    duty-cycled scan at 100 ms aliases with 100 ms beacons: each goes unheard for over a second,
    all four together for more than the bound -- the emulator's option, not the default."""
    one, together = beacon_silences(ScanConfig())
    assert one < 0.3 and together < 0.15, (one, together)
    one, together = beacon_silences(ScanConfig(interval_us=100_000, window_us=50_000))
    assert one > 1.0 and together > 0.3, (one, together)


def test_scan_config_is_checked() -> None:
    with pytest.raises(ValueError, match="scan window"):
        Esp32ScannerFirmware(1, ScanConfig(interval_us=10_000, window_us=20_000))


# -- AT86RF212 ----------------------------------------------------------------------------
def test_dish_half_power_beam_width() -> None:
    d = 0.3
    half = math.radians(beam_width_deg(d) / 2)
    assert dish_gain_db(half, d, 20) - dish_gain_db(0, d, 20) == pytest.approx(-3.0)
    assert dish_gain_db(math.pi, d, 20) - dish_gain_db(0, d, 20) == pytest.approx(-20.0)
    assert beam_width_deg(0.3276) == pytest.approx(70.0)


@given(st.floats(-120, -10), st.floats(-3.14, 3.14), st.lists(st.floats(-5, 5), min_size=4, max_size=4))
def test_ed_quantisation_against_the_table(incident: float, bearing: float, offsets: list[float]) -> None:
    fw = At86rf212NodeFirmware(2, chip_offsets_db=offsets)
    fw.on_frame(100, 7, bearing, [incident] * 4)
    gains = fw.antenna_gains_db(bearing)
    out = records(fw)
    sets = [r for r in out if isinstance(r, AntennaSet)]
    frames = {r.antenna: r for r in out if isinstance(r, RfFrame)}
    for i in range(4):
        power = incident + gains[i]
        if power < fw.sensitivity_dbm:
            assert i not in frames
            continue
        measured = power + offsets[i]
        ed = frames[i].ed
        assert frames[i].rssi_base_dbm == -99 and sets[0].antennas[i].ed == ed
        if -99 < measured < -99 + 84:
            assert abs(ed_to_dbm(ed, -99) - measured) <= 0.5 + 1e-9
        else:
            assert ed == (0 if measured <= -99 else 84)


def test_strongest_antenna_faces_the_emitter() -> None:
    fw = At86rf212NodeFirmware(2)
    for k, bearing in enumerate((0.0, math.pi, math.pi / 2, -math.pi / 2)):
        fw.on_frame(k, k, bearing, [-70.0] * 4)
    sets = [r for r in records(fw) if isinstance(r, AntennaSet)]
    assert [max(range(4), key=lambda i: s.antennas[i].ed) for s in sets] == [0, 1, 2, 3]


def test_set_channel_command_and_unknown_mode_logged() -> None:
    fw = At86rf212NodeFirmware(2)
    fw.receive(encode_frame(NodeCommand(0, 1, 0, 1, bytes([0, 2]))))
    assert fw.base_dbm == -98
    fw.receive(encode_frame(NodeCommand(0, 2, 0, 1, bytes([9, 9]))))
    (log,) = records(fw)
    assert log.kind == "log_text" and "no RSSI_BASE_VAL" in log.text


# -- robot base ---------------------------------------------------------------------------
def run_base(fw: RobotBaseFirmware, seconds: float, t0: int = 0) -> int:
    t = t0
    for _ in range(int(seconds * 100)):
        t += 10_000
        fw.step(t)
    return t


def test_base_clamps_and_accelerates_within_limits() -> None:
    fw = RobotBaseFirmware(limits=BaseLimits(v_max=0.5, w_max=1.0, a_max=1.0))
    fw.receive(encode_frame(VelocityCommand(0, 1, 0, 2000, 3000, 5000)))
    fw.step(0)
    fw.step(100_000)
    assert fw.v == pytest.approx(0.1) and fw.w == pytest.approx(0.4)
    run_base(fw, 1.0, 100_000)
    assert (fw.v, fw.w) == (0.5, 1.0)


def test_watchdog_stops_and_flags() -> None:
    fw = RobotBaseFirmware()
    fw.receive(encode_frame(VelocityCommand(0, 1, 0, 300, 0, 200)))
    run_base(fw, 1.0)
    odometry = [r for r in records(fw) if isinstance(r, Odometry)]
    assert fw.v == 0.0 and fw.counters["watchdog_stops"] == 1
    assert odometry[-1].flags & 1 and not odometry[0].flags & 1
    assert 48 <= len(odometry) <= 51  # 50 Hz


def test_odometry_integrates_and_drifts_by_the_configured_slip() -> None:
    fw = RobotBaseFirmware(slip=Slip(v_scale=0.05))
    fw.receive(encode_frame(VelocityCommand(0, 1, 0, 500, 0, 60000)))
    run_base(fw, 10.0)
    true_distance = 0.5 * 10 - 0.5 * 0.5 / 2  # accelerating at 1 m/s² to 0.5 m/s
    assert fw.x == pytest.approx(true_distance * 1.05, rel=0.01)
    last = [r for r in records(fw) if isinstance(r, Odometry)][-1]
    assert abs(last.x_mm - fw.x * 1000) <= 0.5 * 20 and last.v_mm_s == 500  # sent ≤ 20 ms ago
