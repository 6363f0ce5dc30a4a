"""S1 docking: docked only once the RSSI received while the robot stands confirms it."""

from __future__ import annotations

import math

from rfhoming.host.bearing import Bearing
from rfhoming.host.drivers.aoa import bearing_of
from rfhoming.host.homing.s1_dock import DockController, S1Params
from rfhoming.host.homing.types import Decision, Pose
from rfhoming.protocol.uconnect.items import AngleEvent

POSE = Pose(0.0, 0.0, 1.57)
PARAMS = S1Params(rssi_arrival_dbm=-51.0, align=False)


def _reading(t: float, rssi: int) -> Bearing:
    return bearing_of(t, AngleEvent("D0C0FFEE0001", rssi, 0, 0, 0, 37, "dock", "", int(t * 1000)))


def _feed(dock: DockController, t0: float, rssi: list[int]) -> tuple[float, Decision]:
    """Readings at 50 Hz, a decision after each; the last decision and the time after."""
    t = t0
    decision = dock.decide(POSE)
    for r in rssi:
        dock.on_input(t, POSE, _reading(t, r))
        decision = dock.decide(POSE)
        t += 0.02
    return t, decision


def test_a_lucky_moment_is_not_docked_while_standing_disagrees() -> None:
    """Ten readings at the arrival RSSI (a lucky stretch) make the moving average say docked;
    the standing readings, 6 dB weaker, do not confirm it: no arrival, the robot steps on."""
    dock = DockController(PARAMS)
    t, decision = _feed(dock, 0.0, [-51] * 10)
    assert dock.stage == "confirming" and dock.phase == "docking" and dock.rssi_diff <= PARAMS.alpha_db
    assert not decision.arrived and decision.v == 0.0 and decision.note.startswith("confirming")
    t, decision = _feed(dock, t, [-57] * 60)  # 1.2 s standing
    assert not dock.confirmed and not decision.arrived


def test_standing_readings_at_the_arrival_rssi_confirm() -> None:
    dock = DockController(PARAMS)
    t, decision = _feed(dock, 0.0, [-51] * 10)
    assert not decision.arrived
    t, decision = _feed(dock, t, [-51, -50, -52] * 20)
    assert dock.confirmed and decision.arrived


def test_no_window_is_the_papers_instant_stop() -> None:
    dock = DockController(S1Params(rssi_arrival_dbm=-51.0, align=False, confirm_s=0.0))
    _, decision = _feed(dock, 0.0, [-51] * 10)
    assert decision.arrived


def test_the_last_try_docks() -> None:
    """Standing readings that never confirm: the third confirmation docks anyway (stepping on
    for ever would carry the robot past the station)."""
    dock = DockController(PARAMS)
    t, decision = _feed(dock, 0.0, [-51] * 10)
    tries = 0
    for _ in range(10):
        t, decision = _feed(dock, t, [-57] * 60 + [-51] * 10)  # stand, then a lucky stretch again
        tries += 1
        if decision.arrived:
            break
    assert dock.confirmed and decision.arrived and tries == 3


def test_a_confirmation_runs_its_window_even_if_the_average_rises() -> None:
    """The moving average rises above alpha a moment after the robot stopped: it keeps
    standing until the window is over, rather than stepping on from the average."""
    dock = DockController(PARAMS)
    t, decision = _feed(dock, 0.0, [-51] * 10)
    t, decision = _feed(dock, t, [-60] * 5)
    assert dock.rssi_diff > PARAMS.alpha_db
    assert decision.v == 0.0 and decision.w == 0.0 and decision.note.startswith("confirming")


def test_a_failed_confirmation_steps_on_a_little() -> None:
    """Standing 9 dB short asks S1's rule for a 0.4 m step (0.08 m/dB, capped); after a failed
    confirmation the robot may stand at the docked pose with a weak link, and steps 0.1 m."""
    dock = DockController(PARAMS)
    t, decision = _feed(dock, 0.0, [-51] * 10)
    decisions = []
    for r in [-60] * 60:
        dock.on_input(t, POSE, _reading(t, r))
        decisions.append(dock.decide(POSE))
        t += 0.02
    stepped = [d for d in decisions if d.note == "not confirmed: stepping on"]
    assert len(stepped) == 1 and stepped[0].goal is not None
    assert math.dist(stepped[0].goal, (POSE.x, POSE.y)) <= PARAMS.confirm_step_m + 1e-9 < PARAMS.max_step_m
