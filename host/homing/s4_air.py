"""S4 from the air: fly a lawn-mower over the search area carrying BLE RSSI receivers, localise
every beacon heard with S4's EKF, then fly to one and hold over it.

S4 (CTU thesis, docs/RESULTS.md) localises beacons from receivers carried in a known formation
over a rectangle given relative to the vehicles' start, on a lawn-mower that passes every
beacon within 2 m. Here one vehicle carries the formation: each receiver (a BLE scanner, named by
its node id) sits at a fixed place on the vehicle (``receivers``, metres in its body frame), so
its position is the vehicle's odometry plus that offset turned by the heading -- S4's "MAVs
localised relative to each other, moving in a known formation". The receivers fly ``height_m``
above the beacons (S4 sets the beacon's z to 0 and does not estimate it).

Each control period is one S4 step for every beacon heard so far: the receivers' displacement
since the last step is the input u, their positions and the mean RSSI each heard of the beacon
in the period are the measurements (a receiver that heard nothing adds no row). The filter is
S4's EKF (host.estimation.beacon, the campaign's own). A new beacon starts either from S4's
circle-intersection initialiser over ``n_init`` steps (``init = "circles"``, the thesis) or at
the area's centre with its size as the spread (``"area"``, the default: the campaign found S4's
initialiser the larger error, docs/RESULTS.md "S4 Monte Carlo"). With ``smooth`` the flight's
readings are kept and, when the pattern ends, each beacon and its per-receiver RSSI offsets are
fitted to all of them (``refine_batch``, the campaign's smoother), from the EKF's estimate and
from a 1 m grid over the area, keeping the best fit.
The smoother fits one beacon each control period while the vehicle hovers, so the loop never
waits long on it. After the pattern the vehicle flies to the beacon ``home_on`` (or the one localised most
surely), holds over it ``hold_s`` and reports arrival; the loop's stop leaves the vehicle
holding there (a copter in BRAKE or LOITER).
"""

from __future__ import annotations

import enum
import math
import re
from collections import deque
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from rfhoming.host.drivers.rss import BleRssi
from rfhoming.host.estimation.beacon import (BeaconEkf, CircleInitializer, S4Model, batch_cost, initial_state,
                                             refine_batch)
from rfhoming.host.estimation.fixed import wrap_rad
from rfhoming.host.homing.schema import DBM, M_S, RAD_S, M, S, setting
from rfhoming.host.homing.types import ControllerDefaults, Decision, ParamsError, Pose, velocity_law

FORMATION = {"1": [-0.2, -0.2], "2": [0.4, -0.2], "3": [-0.2, 0.4]}
"""The S4 campaign's formation (S4 leaves it open), an L of 0.6 m sides centred on the path, by receiver node id."""
MAX_BEACONS = 100
"""Beacons localised at most (S4 knows its beacons; a phone walking by is one more): later
addresses are ignored, counted."""
GRID_M = 1.0
"""The smoother also starts from a grid of this spacing over the area ..."""
THIN = 4
MAX_STARTS = 200  # the smoother's grid of starts at most: a wide area gets a coarser grid, not more memory
"""... on every fourth step of the flight: a fit per grid point costs that much less."""
MAX_STEPS = 36_000
"""Steps of readings kept for the smoother: an hour at 10 Hz; an older step is forgotten."""


@dataclass(frozen=True)
class S4Params:
    area: list[float] = setting(factory=lambda: [0.0, 0.0, 4.0, 8.0], low=-10000, high=10000, unit=M, length=4)  # x0, y0, x1, y1 in the vehicle's local frame (S4: 4 x 8 m)
    lane_spacing_m: float = setting(0.8, low=0, above=True, high=100, unit=M)  # lanes along y, this far apart
    receivers: dict[str, list[float]] = setting(factory=lambda: dict(FORMATION), low=-10, high=10, unit=M, length=2)  # node id -> [x, y] on the vehicle
    height_m: float = setting(1.0, low=0, high=1000, unit=M)  # the receivers above the beacons
    p0_dbm: float = setting(-40.23, low=-150, high=30, unit=DBM)  # RSSI at 1 m (S4)
    n: float = setting(2.0, low=1, high=6, unit="(path-loss exponent)")
    q: float = setting(0.05, low=0, above=True, high=100, unit="m^2 per step")  # what S4's filter is told
    r_pos: float = setting(0.05, low=0, above=True, high=100, unit="m^2")
    r_rssi: float = setting(9.0, low=0, above=True, high=10000, unit="dB^2")
    n_init: int = setting(30, low=1, high=10000, unit="steps")  # S4's initialiser
    c_f: float = setting(3.0, low=0, high=1000, unit="(low-pass weight)")
    c_w: float = setting(500.0, low=0, above=True, high=1e6, unit="m^2 x steps")
    init: str = setting("area", choices=("area", "circles"))  # a new beacon: at the area's centre, or S4's initialiser
    smooth: bool = setting(True)  # after the pattern, fit every beacon to all its readings (the campaign's smoother)
    home_on: str = setting("")  # the beacon to hold over (address as `rfhoming listen` prints it); "": the surest
    search_speed: float = setting(0.2, low=0, above=True, high=20, unit=M_S)  # S4: 0.2 m/s
    waypoint_radius_m: float = setting(0.1, low=0, above=True, high=10, unit=M)
    v_max: float = setting(0.5, low=0, above=True, high=20, unit=M_S)  # toward the beacon
    w_max: float = setting(1.0, low=0, above=True, high=10, unit=RAD_S)
    k_w: float = setting(1.5, low=0, above=True, high=20, unit="1/s")
    k_stop: float = setting(0.8, low=0, above=True, high=10, unit="1/s")
    arrival_radius: float = setting(0.15, low=0, above=True, high=10, unit=M)
    hold_s: float = setting(3.0, low=0, high=600, unit=S)  # hover over it this long before reporting arrival
    min_readings: int = setting(20, low=1, high=100000, unit="readings")  # a beacon heard less is not homed on


def lawnmower(area: list[float], spacing: float) -> list[tuple[float, float]]:
    """Corners of the pattern: lanes x = x0, x0 + spacing … x1 along y, alternating direction."""
    x0, y0, x1, y1 = area
    lanes = int(math.floor((x1 - x0) / spacing + 1e-9)) + 1
    out = []
    for i in range(lanes):
        x = x0 + i * spacing
        out += [(x, y0), (x, y1)] if i % 2 == 0 else [(x, y1), (x, y0)]
    return out


@dataclass
class _Beacon:
    """One beacon's RSSI this step, and its initialiser, then its filter."""

    init: CircleInitializer | None
    rssi_sum: np.ndarray
    heard: np.ndarray
    readings: int = 0
    row: int | None = None  # its row of the EKF, once it has one
    estimate: np.ndarray | None = None
    smoothed: np.ndarray | None = None
    history: deque[tuple[int, np.ndarray]] = field(default_factory=lambda: deque(maxlen=MAX_STEPS))  # (step, RSSI)


class Stage(enum.StrEnum):
    """S4's stages: the lawn-mower search, the smoother's pass, homing on the chosen beacon, holding over it."""

    SEARCH = "search"
    SMOOTHING = "smoothing"
    HOMING = "homing"
    HOLDING = "holding"


class SurveyController(ControllerDefaults):
    source = "ble"
    needs_fresh_readings = False  # the pattern goes on through stretches where no beacon is heard

    def __init__(self, params: S4Params) -> None:
        if not params.receivers:
            raise ParamsError("[s4] receivers needs one receiver at least: NODE_ID = [x, y] on the vehicle")
        x0, y0, x1, y1 = params.area
        if not (x1 > x0 and y1 > y0):
            raise ParamsError(f"[s4] area = {params.area} must be [x0, y0, x1, y1] with x1 > x0 and y1 > y0")
        if params.home_on and not re.fullmatch(r"[0-9A-Fa-f]{12}", params.home_on):
            raise ParamsError(f"[s4] home_on = {params.home_on!r}: a beacon's address, 12 hex digits without colons "
                              "(as `rfhoming listen` prints it), or \"\" for the surest")
        if not all(k.isdigit() for k in params.receivers):
            raise ParamsError(f"[s4.receivers] keys are the scanners' node ids (whole numbers), not {list(params.receivers)}")
        self.params = params
        self.nodes = {int(k): i for i, k in enumerate(params.receivers)}
        self.mount = np.array(list(params.receivers.values()), float)
        self.model = S4Model(receivers=len(self.mount), p0_dbm=params.p0_dbm, n=params.n, q=params.q,
                             r_pos=params.r_pos, r_rssi=params.r_rssi, height_m=params.height_m)
        self.waypoints = lawnmower(params.area, params.lane_spacing_m)
        self.centre = np.array([(x0 + x1) / 2, (y0 + y1) / 2])
        self.spread = np.eye(2) * max(x1 - x0, y1 - y0) ** 2 / 4  # the area's half-size as the std
        self.steps = 0
        self.path: deque[np.ndarray] = deque(maxlen=MAX_STEPS)  # the receivers' positions at each step
        self.next_wp = 0
        self.beacons: dict[str, _Beacon] = {}
        self.stage = Stage.SEARCH
        self.target: str | None = None
        self.t = 0.0  # robot time of the newest reading
        self._held_since: float | None = None
        self._previous: np.ndarray | None = None  # the receivers' positions at the last step
        self.ekf: BeaconEkf | None = None  # every beacon's row, once it has one
        self._to_smooth: list[str] = []  # beacons the smoother has still to fit, after the pattern

    @property
    def phase(self) -> str:
        return self.stage

    @property
    def reported(self) -> Any:
        b = self.beacons.get(self.target or "")
        best = None if b is None else b.smoothed if b.smoothed is not None else b.estimate
        return None if best is None else tuple(float(v) for v in best)

    def receivers(self, pose: Pose) -> np.ndarray:
        """Each receiver's position (M, 2): the vehicle's plus its offset turned by the heading."""
        c, s = math.cos(pose.theta), math.sin(pose.theta)
        out: np.ndarray = np.array([pose.x, pose.y]) + self.mount @ np.array([[c, s], [-s, c]])
        return out

    def on_input(self, t: float, pose: Pose, item: Any) -> dict[str, Any] | None:
        if not isinstance(item, BleRssi) or item.node_id not in self.nodes:
            return None
        self.t = t
        m = self.model.receivers
        b = self.beacons.get(item.address)
        if b is None and len(self.beacons) >= MAX_BEACONS:
            return {"address": item.address, "ignored": f"more than {MAX_BEACONS} beacons"}
        if b is None:
            p = self.params
            circles = CircleInitializer(self.model, 1, p.n_init, p.c_f, p.c_w) if p.init == "circles" else None
            b = self.beacons[item.address] = _Beacon(circles, np.zeros(m), np.zeros(m))
        i = self.nodes[item.node_id]
        b.rssi_sum[i] += item.rssi_dbm
        b.heard[i] += 1
        b.readings += 1
        return {"address": item.address, "node": item.node_id, "rssi": item.rssi_dbm}

    def step(self, pose: Pose) -> None:
        """One S4 step for every beacon heard so far, on the readings since the last: one EKF
        over all of them (K rows, host.estimation.beacon runs K beacons at once)."""
        rec = self.receivers(pose)
        u = np.zeros_like(rec) if self._previous is None else rec - self._previous
        self._previous = rec
        self.path.append(rec)
        self.steps += 1
        rows: list[tuple[int, np.ndarray]] = []
        joining: list[tuple[str, np.ndarray, np.ndarray]] = []
        joining_rssi: list[np.ndarray] = []
        for address, b in self.beacons.items():
            with np.errstate(invalid="ignore", divide="ignore"):
                rssi = np.where(b.heard > 0, b.rssi_sum / b.heard, np.nan)
            if b.heard.any():
                b.history.append((self.steps, rssi))
            b.rssi_sum[:] = 0
            b.heard[:] = 0
            if b.row is not None:
                rows.append((b.row, rssi))
            elif b.init is None:  # at the area's centre, then this step's readings
                joining.append((address, self.centre, self.spread))
                joining_rssi.append(rssi)
            else:
                b.init.update(rec[None], rssi[None])
                if b.init.ready:
                    est, cov = b.init.estimate()
                    est = np.where(np.isnan(est), rec.mean(axis=0), est)  # no two circles met: under the receivers
                    joining.append((address, est[0], cov[0]))
        if self.ekf is not None:
            k = len(self.ekf.x)
            heard = np.full((k, self.model.receivers), np.nan)
            for row, rssi in rows:
                heard[row] = rssi
            self.ekf.predict(np.tile(u.reshape(1, -1), (k, 1)))
            self.ekf.update(np.tile(rec.reshape(1, -1), (k, 1)), heard)
        if joining:
            self._join(rec, joining, joining_rssi)
        if self.ekf is not None:
            for b in self.beacons.values():
                if b.row is not None:
                    b.estimate = self.ekf.beacon[b.row].copy()

    def _join(self, rec: np.ndarray, joining: list[tuple[str, np.ndarray, np.ndarray]], rssi: list[np.ndarray]) -> None:
        """New rows of the EKF: beacons started at the area's centre take this step's readings."""
        n = len(joining)
        new = BeaconEkf(self.model, *initial_state(self.model, np.repeat(rec[None], n, axis=0),
                                                   np.array([e for _, e, _ in joining]),
                                                   np.array([c for _, _, c in joining])))
        if rssi:  # the area's start: the first len(rssi) of them
            first = BeaconEkf(self.model, new.x[: len(rssi)], new.p[: len(rssi)])
            first.update(np.tile(rec.reshape(1, -1), (len(rssi), 1)), np.array(rssi))
            new.x[: len(rssi)], new.p[: len(rssi)] = first.x, first.p
        base = 0 if self.ekf is None else len(self.ekf.x)
        if self.ekf is None:
            self.ekf = new
        else:
            self.ekf.x = np.vstack([self.ekf.x, new.x])
            self.ekf.p = np.concatenate([self.ekf.p, new.p])
        for i, (address, _, _) in enumerate(joining):
            self.beacons[address].row = base + i

    def smooth(self, address: str) -> None:
        """One beacon fitted to all the readings kept of it (the campaign's smoother). From one
        start a few metres off Gauss-Newton can settle in a local minimum, so it also starts
        from a grid over the area -- on every ``THIN``-th step, cheaply -- and the best of those
        fits and the EKF's estimate, refined on every step, is kept."""
        b = self.beacons[address]
        first = self.steps - len(self.path) + 1  # the step of path[0]
        kept = [(k, r) for k, r in b.history if k >= first]
        if b.estimate is None or not kept:
            return
        path = np.array(self.path)
        receivers = path[[k - first for k, _ in kept]][:, None]  # (S, 1, M, 2)
        rssi = np.stack([r for _, r in kept])[:, None]  # (S, 1, M)
        x0, y0, x1, y1 = self.params.area
        spacing = max(GRID_M, math.sqrt((x1 - x0) * (y1 - y0) / MAX_STARTS))
        grid = np.stack(np.meshgrid(np.arange(x0, x1 + 1e-9, spacing), np.arange(y0, y1 + 1e-9, spacing)), -1).reshape(-1, 2)
        thin_rec, thin_rssi = (np.repeat(a[::THIN], len(grid), axis=1) for a in (receivers, rssi))
        fits, offsets = refine_batch(self.model, thin_rec, thin_rssi, grid, iterations=6)
        best = fits[int(np.argmin(batch_cost(self.model, thin_rec, thin_rssi, fits, offsets)))]
        starts = np.stack([b.estimate, best])
        receivers, rssi = np.repeat(receivers, 2, axis=1), np.repeat(rssi, 2, axis=1)
        fits, offsets = refine_batch(self.model, receivers, rssi, starts, iterations=6)
        b.smoothed = fits[int(np.argmin(batch_cost(self.model, receivers, rssi, fits, offsets)))]

    def _choose(self) -> str | None:
        """The beacon to hold over: ``home_on``, or the surest of those heard enough."""
        known = {a: b.row for a, b in self.beacons.items() if b.row is not None and b.readings >= self.params.min_readings}
        if self.params.home_on:
            return self.params.home_on.upper() if self.params.home_on.upper() in known else None
        if not known or self.ekf is None:
            return None
        p = self.ekf.p
        return min(known, key=lambda a: float(np.trace(p[known[a], -2:, -2:])))

    def decide(self, pose: Pose, steer_to: tuple[float, float] | None = None) -> Decision:
        self.step(pose)
        p = self.params
        if self.stage is Stage.SEARCH:
            return self._search(pose)
        if self.stage is Stage.SMOOTHING:  # one beacon a control period: no long pause of the loop
            if self._to_smooth:
                address = self._to_smooth.pop(0)
                self.smooth(address)
                return Decision(0.0, 0.0, None, False, f"hovering: smoothing {address}")
            self.stage = Stage.HOMING
        self.target = self._choose()
        goal = self.reported
        if goal is None:
            return Decision(0.0, 0.0, None, False, f"hovering: beacon {p.home_on or 'to home on'} not localised")
        d = math.hypot(goal[0] - pose.x, goal[1] - pose.y)
        if d < p.arrival_radius or (self.stage is Stage.HOLDING and d < 2 * p.arrival_radius):
            if self._held_since is None:
                self.stage, self._held_since = Stage.HOLDING, self.t
            if self.t - self._held_since >= p.hold_s:
                return Decision(0.0, 0.0, goal, True, "arrived: holding over the beacon")
            return Decision(0.0, 0.0, goal, False, "holding over the beacon")
        self.stage, self._held_since = Stage.HOMING, None
        aim = goal if steer_to is None else steer_to
        theta_g = wrap_rad(math.atan2(aim[1] - pose.y, aim[0] - pose.x) - pose.theta)
        v, w = velocity_law(theta_g, d, p.v_max, p.w_max, p.k_w, p.k_stop)
        return Decision(v, w, goal, False, "homing")

    def _search(self, pose: Pose) -> Decision:
        p = self.params
        while self.next_wp < len(self.waypoints) and math.dist(self.waypoints[self.next_wp], pose[:2]) < p.waypoint_radius_m:
            self.next_wp += 1
        if self.next_wp == len(self.waypoints):
            self.stage = Stage.SMOOTHING if p.smooth else Stage.HOMING
            self._to_smooth = sorted(a for a, b in self.beacons.items() if b.estimate is not None)
            return Decision(0.0, 0.0, None, False, "search done")
        wx, wy = self.waypoints[self.next_wp]
        rest = math.hypot(wx - pose.x, wy - pose.y) + sum(
            math.dist(a, b) for a, b in zip(self.waypoints[self.next_wp:], self.waypoints[self.next_wp + 1:]))
        theta_g = wrap_rad(math.atan2(wy - pose.y, wx - pose.x) - pose.theta)
        v, w = velocity_law(theta_g, rest, p.search_speed, p.w_max, p.k_w, p.k_stop)
        return Decision(v, w, None, False, f"search: toward corner {self.next_wp + 1} of {len(self.waypoints)}")

    def estimate(self) -> dict[str, Any]:
        """The EKF's beacons each step; the smoothed ones too once fitted."""
        def xy(v: np.ndarray) -> list[float]:
            return [round(float(c), 3) for c in v]

        out: dict[str, Any] = {"beacons": {a: xy(b.estimate) for a, b in sorted(self.beacons.items())
                                           if b.estimate is not None}}
        smoothed = {a: xy(b.smoothed) for a, b in sorted(self.beacons.items()) if b.smoothed is not None}
        if smoothed:
            out["smoothed"] = smoothed
        return {**out, "home_on": self.target, "corner": self.next_wp}
