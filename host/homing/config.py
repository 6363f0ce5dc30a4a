"""One TOML file for mounting, calibration, controller gains and loop limits.

``rfhoming config --print-default`` prints :data:`DEFAULT_TOML`, commented; every key may be
left out, and unknown keys are refused with the list of known ones.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

from rfhoming.host import portspec
from rfhoming.host.estimation.ranging import LogDistance
from rfhoming.host.homing.avoidance import AvoidParams
from rfhoming.host.homing.grid import GridParams
from rfhoming.host.homing.s0_aoa import S0Params
from rfhoming.host.homing.s1_dock import S1Params
from rfhoming.host.homing.s2_rss import S2Params
from rfhoming.host.homing.s3_trilat import TrilatParams
from rfhoming.host.homing.s4_air import S4Params
from rfhoming.host.homing.schema import DBM, ConfigError, M, S, build, setting
from rfhoming.protocol.textfile import read_toml

__all__ = ["DEFAULT_TOML", "SECTIONS", "Config", "ConfigError", "load"]


@dataclass(frozen=True)
class Mounting:
    yaw_offset_deg: float = setting(0.0, low=-360, high=360, unit="degrees")  # board boresight vs robot heading, CCW
    azimuth_sign: int = setting(-1, choices=(-1, 1))  # the XPLR-AOA reports left as negative; -1 turns that into CCW
    upside_down: bool = setting(False)  # mirrors the azimuth once more
    # where each sensor sits on the robot (base_link: x ahead, y left, z up; REP 103): the
    # transforms base_link -> aoa_link / laser / rss_link / ble_link of a recording
    aoa_xyz_m: tuple[float, float, float] = setting((0.0, 0.0, 0.0), low=-10, high=10, unit=M, length=3)
    laser_xyz_m: tuple[float, float, float] = setting((0.0, 0.0, 0.0), low=-10, high=10, unit=M, length=3)
    laser_yaw_deg: float = setting(0.0, low=-360, high=360, unit="degrees")  # its 0 rad beam vs the robot heading, CCW
    rss_xyz_m: tuple[float, float, float] = setting((0.0, 0.0, 0.0), low=-10, high=10, unit=M, length=3)
    ble_xyz_m: tuple[float, float, float] = setting((0.0, 0.0, 0.0), low=-10, high=10, unit=M, length=3)

    def __post_init__(self) -> None:
        for name in ("aoa_xyz_m", "laser_xyz_m", "rss_xyz_m", "ble_xyz_m"):
            object.__setattr__(self, name, tuple(float(v) for v in getattr(self, name)))

    def to_robot(self, azimuth_deg: float) -> float:
        """Board azimuth (degrees, board convention) -> θs in the robot frame (rad, CCW)."""
        sign = self.azimuth_sign * (-1 if self.upside_down else 1)
        return math.radians(sign * azimuth_deg + self.yaw_offset_deg)


@dataclass(frozen=True)
class Calibration:
    p0_dbm: float = setting(-59.0, low=-150, high=30, unit=DBM)  # RSSI at d0 (log-distance)
    n: float = setting(2.2, low=1, high=6, unit="(path-loss exponent)")
    d0_m: float = setting(1.0, low=0, above=True, high=100, unit=M)
    ed_scale_db: float = setting(1.0, low=0, above=True, high=10, unit="dB per ED step")  # AT86RF212

    @property
    def model(self) -> LogDistance:
        return LogDistance(self.p0_dbm, self.n, self.d0_m)


@dataclass(frozen=True)
class LoopSettings:
    # emergency-stop when a required stream is older than this (robot time)
    stale_timeout_s: float = setting(0.3, low=0, above=True, high=60, unit=S)
    # ... or than this many of its event intervals, if longer; 0: fixed timeout
    stale_intervals: float = setting(3.0, low=0, high=100, unit="event intervals")
    # from this age on, speed falls linearly to 0 at the stale timeout, braking hard
    slow_after_s: float = setting(0.1, low=0, high=60, unit=S)
    # stop when the base is silent this long (wall time; inf in lockstep simulation)
    odometry_wall_timeout_s: float = setting(0.5, low=0, above=True, high=math.inf, inf=True, unit=S)
    control_period_s: float = setting(0.1, low=0, above=True, high=10, unit=S)
    max_time_s: float = setting(180.0, low=0, above=True, high=math.inf, inf=True, unit=S)  # robot time
    command_timeout_ms: int = setting(300, low=10, high=60000, unit="ms")  # the base stops if no command follows
    # a base with no brake mode (a ROS 2 base) drives no faster than lets it stop within this
    # after its data ends, shedding speed at brakeless_decel_m_s2 (host/homing/loop.py)
    stop_within_m: float = setting(0.25, low=0, above=True, high=100, unit=M)
    brakeless_decel_m_s2: float = setting(1.0, low=0, above=True, high=50, unit="m/s²")


@dataclass(frozen=True)
class PlanSettings:
    enabled: bool = setting(True)  # plan on an occupancy grid whenever the base sends range scans
    replan_s: float = setting(1.0, low=0, above=True, high=60, unit=S)  # at most one plan asked for this often
    # a plan asked for at robot time t takes effect at t + latency_s, whatever the wall clock did
    latency_s: float = setting(0.1, low=0, high=10, unit=S)
    goal_moved_m: float = setting(0.5, low=0, high=100, unit=M)  # re-plan when the goal moved this far
    strayed_m: float = setting(0.6, low=0, above=True, high=100, unit=M)  # ... or the robot is this far off the path
    refresh_s: float = setting(5.0, low=0, above=True, high=600, unit=S)  # ... or the map changed and this long passed
    # wait for a plan not done by its robot time (lockstep, replays); live, control goes on on the old path
    wait: bool = setting(False)
    lookahead_m: float = setting(0.8, low=0, above=True, high=10, unit=M)
    integrate_s: float = setting(0.3, low=0, high=60, unit=S)  # add a scan to the map at most this often
    grid: GridParams = field(default_factory=GridParams)


@dataclass(frozen=True)
class Config:
    mounting: Mounting = field(default_factory=Mounting)
    calibration: Calibration = field(default_factory=Calibration)
    loop: LoopSettings = field(default_factory=LoopSettings)
    s0: S0Params = field(default_factory=S0Params)
    avoid: AvoidParams = field(default_factory=AvoidParams)
    plan: PlanSettings = field(default_factory=PlanSettings)
    s2: S2Params = field(default_factory=S2Params)
    s1: S1Params = field(default_factory=S1Params)
    trilat: TrilatParams = field(default_factory=TrilatParams)
    s4: S4Params = field(default_factory=S4Params)
    devices: dict[str, portspec.PortSpec] = field(default_factory=dict)  # [devices.NAME]: port specs

    @property
    def avoid_obstacles(self) -> bool:
        return self.avoid.enabled

    def for_lockstep(self) -> Config:
        """This config for a simulation whose world waits for the host (lockstep). There wall
        time means nothing, so the wall-clock odometry check is off: a loaded machine must not
        change a run. Every robot-time fail-safe stays, and the loop waits for a plan that is not
        done by its robot time."""
        return replace(self, loop=replace(self.loop, odometry_wall_timeout_s=math.inf),
                       plan=replace(self.plan, wait=True))


SECTIONS = {"mounting": Mounting, "calibration": Calibration, "loop": LoopSettings, "s0": S0Params,
            "avoid": AvoidParams, "plan": PlanSettings, "s2": S2Params, "s1": S1Params,
            "trilat": TrilatParams, "s4": S4Params}


def load(path: Path | str | None) -> Config:
    """The config in ``path`` (None: the defaults); ConfigError names the key to fix."""
    if path is None:
        return Config()
    raw = read_toml(path, "config", ConfigError)
    devices = raw.pop("devices", {})
    unknown = set(raw) - set(SECTIONS)
    if unknown:
        raise ConfigError(f"{path}: unknown sections {sorted(unknown)}; known: {sorted(SECTIONS)}")
    if not isinstance(devices, dict):
        raise ConfigError(f"{path}: devices must be tables [devices.ROLE] (ROLE: {', '.join(DEVICE_ROLES)})")
    return replace(from_tables(raw, path), devices=_devices(devices, path))


def from_tables(raw: dict[str, Any], source: Any) -> Config:
    """A config from its sections' tables (a TOML file's, or :func:`to_tables`' own)."""
    config = Config(**{name: build(cls, raw.get(name, {}), name, source) for name, cls in SECTIONS.items()})
    for problem in _relations(config):
        raise ConfigError(f"{source}: {problem}")
    return config


def to_tables(config: Config) -> dict[str, Any]:
    """The config's sections as plain tables (no ports): what a run's capture records, so a
    replay runs the loop exactly as configured, whatever file or code made the config."""
    def plain(table: dict[str, Any]) -> dict[str, Any]:  # TOML has no None: a key left out keeps its default
        return {k: plain(v) if isinstance(v, dict) else v for k, v in table.items() if v is not None}

    return {name: plain(asdict(getattr(config, name))) for name in SECTIONS}


def _relations(config: Config) -> list[str]:
    """Settings that are each in range but do not fit together."""
    loop, s1, grid, avoid = config.loop, config.s1, config.plan.grid, config.avoid
    problems = []
    if not loop.slow_after_s < loop.stale_timeout_s:
        problems.append(f"[loop] slow_after_s = {loop.slow_after_s} must be below stale_timeout_s = "
                        f"{loop.stale_timeout_s} (seconds)")
    if not s1.leave_dbm < s1.enter_dbm:
        problems.append(f"[s1] leave_dbm = {s1.leave_dbm} must be below enter_dbm = {s1.enter_dbm} (dBm: the "
                        "docking stage's hysteresis)")
    if not s1.v_min <= s1.v_max:
        problems.append(f"[s1] v_min = {s1.v_min} must be at most v_max = {s1.v_max} (m/s)")
    if not avoid.obs_threshold2 < avoid.obs_threshold1:
        problems.append(f"[avoid] obs_threshold2 = {avoid.obs_threshold2} (stop) must be below obs_threshold1 = "
                        f"{avoid.obs_threshold1} (slow down), in metres")
    if grid.size_m / grid.resolution > MAX_GRID_CELLS:
        problems.append(f"[plan.grid] size_m / resolution = {grid.size_m / grid.resolution:.0f} cells a side; at "
                        f"most {MAX_GRID_CELLS} (a larger resolution in metres, or a smaller size_m)")
    return problems


MAX_GRID_CELLS = 4000
"""Cells on a side of the planning grid at most: 16 M cells, the memory a robot computer can spare."""


DEVICE_ROLES = ("aoa", "base", "rss", "ble")


def _devices(tables: dict[str, Any], path: Path | str) -> dict[str, portspec.PortSpec]:
    """``[devices.ROLE]`` tables -> port specs; the command line's --ROLE overrides them."""
    out = {}
    for role, table in tables.items():
        if role not in DEVICE_ROLES or not isinstance(table, dict):
            raise ConfigError(f"[devices.{role}] in {path}: the devices are {', '.join(DEVICE_ROLES)}, "
                              "each a table with port = \"KIND:WHERE\" and optional settings")
        try:
            out[role] = portspec.from_table(table, f"devices.{role}")
        except portspec.PortSpecError as exc:
            raise ConfigError(f"{path}: [devices.{role}]: {exc}") from None
    return out


DEFAULT_TOML = """\
# rfhoming configuration. Every key is optional; these are the defaults.

[mounting]               # how the XPLR-AOA sits on the robot
yaw_offset_deg = 0.0     # its boresight, degrees CCW from the robot heading
azimuth_sign = -1        # the board reports left as negative: -1 makes it CCW
upside_down = false      # mirrors the azimuth once more
# where each sensor sits on the robot, metres in base_link (x ahead, y left, z up): a
# recording's /tf_static base_link -> aoa_link, laser, rss_link, ble_link
aoa_xyz_m = [0.0, 0.0, 0.0]
laser_xyz_m = [0.0, 0.0, 0.0]
laser_yaw_deg = 0.0      # the range scanner's 0 rad beam, degrees CCW from the robot heading
rss_xyz_m = [0.0, 0.0, 0.0]
ble_xyz_m = [0.0, 0.0, 0.0]

[calibration]            # RSSI -> distance, RSSI(d) = p0_dbm - 10 n log10(d / d0_m)
p0_dbm = -59.0
n = 2.2
d0_m = 1.0
ed_scale_db = 1.0        # AT86RF212: dB per ED step (datasheet 1.03)

[loop]
stale_timeout_s = 0.3    # emergency-stop the robot when a required stream is older than this
stale_intervals = 3.0    # ... or than this many event intervals (median of the last 20), if that is longer
slow_after_s = 0.1       # from this age on, slow down (base brake mode), reaching 0 at the stale timeout
odometry_wall_timeout_s = 0.5  # stop when the base is silent this long, in wall time (inf: lockstep sims)
control_period_s = 0.1
max_time_s = 180.0       # give up after this long
command_timeout_ms = 300 # the base stops by itself if no newer command arrives
stop_within_m = 0.25     # a base with no brake mode (ROS 2) drives no faster than lets it stop this soon
brakeless_decel_m_s2 = 1.0  # ... at its own deceleration (Create 3: 0.9; Nav2's velocity smoother: 2.5)

[s0]                     # AoA homing (S0): the paper's values, and what it left open
k = 0.3                  # parallax (Kohonen) gain per reading (paper 0.8 per 0.1 s)
buffer = 20
tau = 10.0               # vector-goal time weighting, in readings
z_threshold = 1.645
err_threshold = 0.3
arrival_radius = 0.3     # m
arrival_agreement = 0.6  # m, |parallax goal - vector goal| at arrival
v_max = 0.7              # m/s
w_max = 1.2              # rad/s
k_w = 1.5                # omega = k_w * goal angle
k_stop = 0.8             # v <= k_stop * goal distance (no overshoot)
max_abs_azimuth_deg = 70.0
unambiguous_deg = 60.0   # only readings this near the boresight move the bearing estimate
disambiguation_s = 1.2   # turn in place this long at the start to tell front from back
disambiguation_w = 0.8
folded = true            # the board folds bearings into +-90 deg; false for a 360-degree sensor
close_fusion_m = 2.0     # nearer than this, vector goals pull the parallax goal (0: paper's rule)
close_fusion_gain = 0.1
ray_fusion = false       # true: report a fusion of the readings within 3 m (calibrated ranges)
fusion_min_readings = 10 # readings within 3 m of the goal before the fusion is reported

[avoid]                  # S0 Appendix B, on the base's front range scan (when it sends one)
enabled = true
obs_threshold1 = 1.5     # m: slow down and steer to the freer side
obs_threshold2 = 0.35    # m: stop and turn
side_threshold = 0.4     # m: turn away from a side this close
w_turn = 1.0             # rad/s
release_s = 1.5          # keep the chosen side until the centre is clear this long

[plan]                   # occupancy grid + A* (S2's full system), when the base sends scans
enabled = true
replan_s = 1.0           # at most one plan asked for this often (robot time)
latency_s = 0.1          # a plan asked for at robot time t takes effect at t + latency_s
goal_moved_m = 0.5       # re-plan when the goal moved this far since the last plan,
strayed_m = 0.6          # ... or the robot is this far from its path,
refresh_s = 5.0          # ... or the map changed and this long passed
wait = false             # wait for a late plan (lockstep, replays); live, go on on the old path
lookahead_m = 0.8        # steer to the path point this far ahead
integrate_s = 0.3        # add a scan to the map at most this often

[s2]                     # RSS direction homing (S2): four dishes + particle filter
p0_dbm = -40.0           # the emitter at 1 m through an isotropic antenna
n = 2.0
peak_gain_db = 6.6       # the dishes' peak gain (0.3 m at 915 MHz)
arrival_range_m = 0.25   # stop when the estimated range is below this (S2's own: 0.5)
min_fixes = 10           # fixes before the first goal
v_max = 0.4
w_max = 1.0
k_w = 1.5
k_stop = 0.8
search_w = 0.5           # turn while no fix has come yet
seed = 0                 # the particle filter's random stream (reproducible runs)
motion = "full"          # "full": grid + A* (when scans come); "preliminary": S2's rules
obstacle_m = 0.2         # preliminary: turn until clear when an obstacle is this close ahead
body_radius_m = 0.25     # preliminary: obstacle_m is from the robot's round body, not the scanner
touch_m = 0.05           # preliminary: this near the body anywhere in the scan counts as ahead
likelihood = "bounded"   # particle weights: "bounded" (ours: a range as an upper bound, walls); "s2" (the paper's)
dish_offsets_db = [0.0, 0.0, 0.0, 0.0]  # x1, x2, y1, y2: each dish's own offset, subtracted (calibration)

[s1]                     # docking (S1): the station's AoA and RSSI of the robot's tag
g_a = 0.25               # heading step per dB of RSSI_diff per degree of AoA change
g_d = 0.08               # m of forward step per dB of RSSI_diff
alpha_db = 1.0           # docked when RSSI_diff <= alpha
beta_db = 8.0            # re-align (rotate delta) when RSSI_diff < beta and |AoA| > gamma
gamma_deg = 20.0
delta_deg = 30.0
n = 10                   # moving-average length of RSSI and AoA
rssi_arrival_dbm = -51.0
enter_dbm = -73.0        # stage hysteresis: docking above -73, mission below -76
leave_dbm = -76.0
v_min = 0.1
v_max = 0.25
w_max = 0.52
max_step_m = 0.4         # cap on one forward step
heading_tolerance_deg = 3.0
position_tolerance_m = 0.03
align = true             # at the end, turn onto the station's axis fitted from the readings
standoff_m = 0.3         # where rssi_arrival_dbm is received (the docked position)
path_n = 2.0             # path-loss exponent for the fit's RSSI ranges
align_min_spread_m = 0.5 # the fit needs this much movement along the approach
# mission_goal = [0.4, 3.6]  # the station on the robot's map: drive there before the docking stage (default: wait)
mission_stop_m = 0.8     # the mission stage stops this far from mission_goal

[trilat]                 # S3: go to a goal, localised on BLE beacons at known places
goal = [0.0, 0.0]        # where to go, in the beacons' frame (m)
p0_dbm = -64.3           # a beacon's RSSI at 1 m (S3 Table I)
n = 2.7
kalman_q = 0.05
kalman_r = 16.0
fresh_s = 2.0            # use beacons heard within this long
max_range_m = 10.0       # no range beyond this is believed
offset_gain = 0.05       # how far each fix pulls the odometry offset
min_fixes = 10
arrival_radius = 0.3
v_max = 0.4
w_max = 1.0
k_w = 1.5
k_stop = 0.8
robust_fit = true        # each fix in dB with a Huber loss (false: S3's linear least squares of ranges)
huber_db = 3.0
localise_s = 2.0         # stand this long first; the offset starts from the mean readings (0: from the first fix)
confirm_s = 2.0          # at arrival stand this long and re-solve from the standing readings (0: the paper's stop)
confirm_settle_s = 0.2
confirm_radius = 0.5     # the standing fix must be this near the goal, else go on
self_calibrate = true    # fit the offset with P0, n and each beacon's own offset over the path's readings
history_s = 150.0        # the readings that fit is made of
place_m = 0.5            # readings within one such cell of the path are one observation
calibrate_every_s = 0.5
confirm_tries = 3        # the last confirmation arrives whatever it says
survey_m = 1.5           # at the goal, drive a square this wide about it before standing (0: none)
survey_tol_m = 0.3       # a survey that moved the offset less than this ends the surveys
survey_max = 3
survey_min = 2           # surveys before one that moved the offset little may end them
survey_grow_m = 1.0      # each further survey is this much wider (new places)
survey_margin_m = 0.25   # the survey's corners stay this far inside the beacons' box (negative: outside)

[trilat.anchors]         # beacon address (as rfhoming listen prints it) = [x, y]; at least three

[s4]                     # S4 from the air: lawn-mower survey, EKF per beacon, then hold over one
area = [0.0, 0.0, 4.0, 8.0]  # x0, y0, x1, y1 in the vehicle's local frame (m; S4's 4 x 8 m)
lane_spacing_m = 0.8     # lanes along y, this far apart
height_m = 1.0           # the receivers' height above the beacons
p0_dbm = -40.23          # RSSI at 1 m (S4)
n = 2.0
q = 0.05                 # what S4's filter is told: receiver motion, positions, RSSI
r_pos = 0.05
r_rssi = 9.0
n_init = 30              # S4's circle-intersection initialiser: steps, low-pass weight, covariance
c_f = 3.0
c_w = 500.0
home_on = ""             # the beacon to hold over (its address); "": the one localised most surely
search_speed = 0.2       # m/s along the pattern (S4)
waypoint_radius_m = 0.1
v_max = 0.5              # m/s toward the beacon
w_max = 1.0
k_w = 1.5
k_stop = 0.8
arrival_radius = 0.15
hold_s = 3.0             # hover over it this long before reporting arrival
min_readings = 20        # a beacon heard less is not homed on

# [s4.receivers]         # BLE scanner node id = [x, y] on the vehicle (m, x ahead, y left); by
# 1 = [-0.2, -0.2]       # default the S4 campaign's formation, an L of 0.6 m sides centred on it
# 2 = [0.4, -0.2]
# 3 = [-0.2, 0.4]

# [devices.ROLE]: the ports of `rfhoming run` (ROLE: aoa, base, rss, ble), each a port spec
# plus any of its settings; --aoa/--base/--rss/--ble on the command line override them.
# [devices.aoa]
# port = "xplr-aoa:/dev/ttyUSB0"
# baud = 1000000
# flow = "rtscts"
# tags = ["CCF9578E0D8A"]
# [devices.base]
# port = "base:/dev/ttyACM0"
# baud = 115200
"""
