"""Range scans carry their geometry exactly (record 0x23: first and last beam in µrad, the
sensor's range): the host's beams are the emulator's to well under 0.1 mrad. Version-1
records (0x22, whole-mrad step) still decode."""

from __future__ import annotations

import math

import numpy as np
from hypothesis import given
from hypothesis import strategies as st

from rfhoming.firmware.robot_base import RobotBaseFirmware
from rfhoming.host.drivers.robot_base import SCAN_V1_RANGE_MAX, scan_of
from rfhoming.protocol.frames import FrameDecoder, RangeScan, RangeScanV2, encode_frame

BEAMS = 181


def sent_scan(angle_min: float, angle_max: float, n: int, range_max: float = 8.0):
    fw = RobotBaseFirmware()
    fw.send_scan(angle_min, angle_max, range_max, [1.0] * n)
    (record,) = [r for r in FrameDecoder().feed(fw.read()) if r.kind.startswith("range_scan")]
    return record


def test_the_emulators_181_beams_over_a_half_turn_arrive_exactly() -> None:
    record = sent_scan(-math.pi / 2, math.pi / 2, BEAMS)
    assert isinstance(record, RangeScanV2)
    scan = scan_of(record)
    beams = scan.angle_min + scan.angle_increment * np.arange(len(scan.ranges))
    truth = np.linspace(-math.pi / 2, math.pi / 2, BEAMS)  # emulator/devices.py casts these
    assert np.max(np.abs(beams - truth)) < 1e-6  # 0.1 mrad is the bar; µrad ends give 1 µrad
    assert scan.angle_max == math.pi / 2 or abs(scan.angle_max - math.pi / 2) < 1e-6
    assert scan.range_max == 8.0


@given(st.floats(-3.14, 3.14), st.floats(-3.14, 3.14), st.integers(1, 255))
def test_any_geometry_survives_to_a_microradian(a: float, b: float, n: int) -> None:
    scan = scan_of(sent_scan(a, b, n))
    assert abs(scan.angle_min - a) <= 1e-6
    if n > 1:
        assert abs(scan.angle_max - b) <= 1e-6
    assert len(scan.ranges) == n


def test_a_version_1_record_still_decodes_with_its_own_step() -> None:
    old = RangeScan(0, 1, 2, -1571, 17, (1200, 0, 980))
    (got,) = FrameDecoder().feed(encode_frame(old))
    assert got == old
    scan = scan_of(got)
    assert (scan.angle_min, scan.angle_increment, scan.ranges) == (-1.571, 0.017, (1.2, None, 0.98))
    assert scan.range_max == SCAN_V1_RANGE_MAX  # version 1 never said the sensor's range
