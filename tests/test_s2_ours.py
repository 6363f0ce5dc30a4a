"""S2's node, ours: near the emitter an ED at its maximum is flagged, and the controller counts
such a fix as "as near as the radio can tell" when it confirms arrival; a turn in place gives
the dishes' offsets."""

from __future__ import annotations

import math

import pytest

from rfhoming.firmware.at86rf212_node import At86rf212NodeFirmware
from rfhoming.host.drivers.rss import AntennaPowers, Associator, RssDriver
from rfhoming.host.homing.s2_rss import Motion, RssController, S2Params
from rfhoming.host.homing.types import Pose
from rfhoming.host.ports import HostPort
from rfhoming.protocol.frames import AntennaReading, AntennaSet
from rfhoming.protocol.frames.codec import encode_frame


def _driver() -> RssDriver:
    return RssDriver(HostPort("loop://"), reconnect=False)


def test_an_antenna_set_flags_the_saturated_chips() -> None:
    d = _driver()
    eds = (84, 60, 84, 10)
    d.on_chunk(encode_frame(AntennaSet(3, 1, 1000, 7, 1, 0, -99, 0b1111,
                                       tuple(AntennaReading(ed, 255, 0) for ed in eds))), 1.0)
    items = []
    while (item := d.out.get_nowait()) is not None:
        items.append(item)
    (powers,) = [r for r in items if isinstance(r, AntennaPowers)]
    assert powers.dbm == (-15.0, -39.0, -15.0, -89.0)
    assert powers.saturated == (True, False, True, False)


def test_the_associator_carries_the_flags() -> None:
    a = Associator()
    for i, sat in enumerate((False, True, False, False)):
        done = a.add(1, 5, i, -20.0 - i, 10.0 + 0.001 * i, sat)
    (powers,) = done
    assert powers.saturated == (False, True, False, False)
    assert AntennaPowers(0.0, 1, 1, (-1.0, -1.0, -1.0, -1.0)).saturated == (False,) * 4


def _after(saturated: bool) -> str:
    """Ours beside an emitter 0.1 m ahead whose strongest dish reads -15 dBm (the ED's top), a
    floor that with the host's constants is 0.32 m: arrived only if it knows the chip saturated."""
    c = RssController(S2Params(p0_dbm=-25.0, n=2.0, peak_gain_db=0.0, spin_calibration=False, confirm_s=0.0))
    sat = (saturated, False, False, False)
    for k in range(20):
        c.on_input(0.05 * k, Pose(0.0, 0.0, 0.0), AntennaPowers(0.05 * k, 1, k, (-15.0, -35.0, -30.0, -30.0), sat))
    c.pf.x[0], c.pf.x[1] = 0.1, 0.0  # the filter (not under test) has it 0.1 m ahead
    return c.decide(Pose(0.0, 0.0, 0.0)).note


def test_saturated_fixes_confirm_arrival() -> None:
    assert _after(True) == "arrived"
    assert _after(False) != "arrived"


def test_a_turn_in_place_measures_the_dishes_offsets() -> None:
    """Ours turns in place first; each dish's mean power over the turn, less the four's mean, is
    its offset, wherever the emitter is; the filter then restarts on the corrected readings."""
    node = At86rf212NodeFirmware(1)
    offsets = (3.0, -4.0, 0.5, 0.5)
    emitter = (2.0, 1.0)
    c = RssController(S2Params(p0_dbm=-30.0, n=2.0, peak_gain_db=6.6, dish_offsets_db=(0.0, 9.0, 0.0, -9.0)))
    assert c.phase == "calibrating"
    t, heading, k = 0.0, 0.0, 0
    while c.phase == "calibrating" and t < 60:
        pose = Pose(0.0, 0.0, heading)
        bearing = math.atan2(emitter[1], emitter[0]) - heading
        incident = -30.0 - 20 * math.log10(math.hypot(*emitter))
        dbm = tuple(incident + g + o for g, o in zip(node.antenna_gains_db(bearing), offsets))
        c.on_input(t, pose, AntennaPowers(t, 1, k, dbm))  # type: ignore[arg-type]
        d = c.decide(pose)
        heading += d.w * 0.05
        t, k = t + 0.05, k + 1
    assert c.spins == 1 and c.phase == "homing"
    assert all(abs(a - (b - sum(offsets) / 4)) < 0.3 for a, b in zip(c.offsets, offsets))
    x, y = c.pf.estimate()
    assert math.atan2(y, x) == pytest.approx(math.atan2(emitter[1], emitter[0]), abs=0.2)


def _beside(confirm_s: float, seconds: float) -> list[str]:
    """Ours with the filter and the dishes agreeing that the emitter is 0.1 m ahead, for
    ``seconds`` of fixes (20 a second): the notes of its decisions."""
    c = RssController(S2Params(p0_dbm=-25.0, n=2.0, peak_gain_db=0.0, spin_calibration=False, confirm_s=confirm_s))
    notes = []
    for k in range(int(seconds * 20)):
        c.on_input(0.05 * k, Pose(0.0, 0.0, 0.0), AntennaPowers(0.05 * k, 1, k, (-5.0, -25.0, -20.0, -20.0)))
        c.pf.x[0], c.pf.x[1] = 0.1, 0.0
        notes.append(c.decide(Pose(0.0, 0.0, 0.0)).note)
    return notes


def test_arrival_holds_for_confirm_s_while_creeping_on() -> None:
    notes = _beside(2.0, 3.0)
    first = notes.index("arrived")
    assert 2.0 <= 0.05 * (first - notes.index("homing")) <= 2.1  # close from the first homing step
    assert set(notes[notes.index("homing"):first]) == {"homing"}
    assert _beside(0.0, 1.0)[9:10] == ["arrived"]  # min_fixes 10: the tenth fix homes and is close


def test_a_robot_kept_in_one_place_turns_again() -> None:
    """Homing toward an emitter it never nears (the dishes say 3 m), the robot held in place:
    after stuck_s it turns in place again, and then homes with the turn's offsets."""
    c = RssController(S2Params(p0_dbm=-30.0, n=2.0, peak_gain_db=0.0, stuck_s=10.0))
    c.motion = Motion.HOMING  # as after the first turn
    notes = []
    for k in range(20 * 20):
        c.on_input(0.05 * k, Pose(0.0, 0.0, 0.0), AntennaPowers(0.05 * k, 1, k, (-40.0, -60.0, -50.0, -50.0)))
        notes.append(c.decide(Pose(0.0, 0.0, 0.0)).note)
    turned = notes.index("stuck: turning in place again")
    assert 10.0 <= 0.05 * turned <= 11.0
    assert c.phase == "calibrating"
