"""S0 homing: the controller alone, then the closed loop through the emulator's ptys."""

from __future__ import annotations

import asyncio
import io
import json
import math
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from loops import loop_on

from rfhoming.campaigns.closed_loop import PipePort
from rfhoming.emulator.faults import Fault
from rfhoming.emulator.runtime import Emulator
from rfhoming.emulator.scenario import Scenario, ScenarioError, load
from rfhoming.host.capture import CaptureWriter
from rfhoming.host.homing.config import DEFAULT_TOML, Config, ConfigError, LoopSettings, Mounting
from rfhoming.host.homing.config import load as load_config
from rfhoming.host.homing.loop import RunLog
from rfhoming.host.homing.s0_aoa import S0Homing, S0Params
from rfhoming.host.homing.s3_trilat import TrilatParams
from rfhoming.host.homing.types import Pose
from rfhoming.host.ports import HostPort
from rfhoming.host.replay import ReplayPort, Sequencer, load_capture
from rfhoming.host.session import recorded_kind


# -- the controller alone -------------------------------------------------------------------
def feed(ctrl: S0Homing, target: tuple[float, float], poses: list[Pose], mirror_behind: bool = True,
         rng: np.random.Generator | None = None) -> None:
    """Readings as the board gives them: folded into ±90°, CCW robot frame."""
    rng = rng or np.random.default_rng(0)
    for k, pose in enumerate(poses):
        rel = math.remainder(math.atan2(target[1] - pose.y, target[0] - pose.x) - pose.theta, 2 * math.pi)
        if mirror_behind and abs(rel) > math.pi / 2:
            rel = math.copysign(math.pi, rel) - rel
        d = math.hypot(target[0] - pose.x, target[1] - pose.y) * (1 + rng.uniform(-0.1, 0.1))
        ctrl.on_reading(0.1 * k, pose, rel + rng.normal(0, math.radians(2)), d)


@pytest.mark.parametrize("target", [(5.0, 2.0), (-5.0, 2.0), (-4.0, -6.0)])
def test_turning_in_place_tells_front_from_back(target) -> None:
    ctrl = S0Homing()
    spin = [Pose(0, 0, 0.08 * k) for k in range(20)]  # the disambiguation turn
    feed(ctrl, target, spin)
    assert ctrl.phase == "homing"
    true_bearing = math.atan2(target[1], target[0])
    assert abs(math.remainder(ctrl._last_theta_world - true_bearing, 2 * math.pi)) < math.radians(6)


def test_parallax_and_vector_goals_converge_and_arrive() -> None:
    ctrl = S0Homing()
    target = (6.0, 3.0)
    feed(ctrl, target, [Pose(0, 0, 0.08 * k) for k in range(20)])
    heading = math.atan2(3, 6)
    path = [Pose(0.05 * k * math.cos(heading) + 0.2 * math.sin(k / 5), 0.05 * k * math.sin(heading), heading) for k in range(100)]
    feed(ctrl, target, path)
    assert ctrl.g_p is not None and math.dist(ctrl.reported, target) < 0.5
    near = Pose(5.85, 2.95, heading)
    decision = ctrl.decide(near)
    assert decision.arrived and decision.v == 0.0


def test_running_z_test_matches_the_buffer_statistics() -> None:
    """The per-reading z-test keeps running sums; it must say what the buffer's mean and std say."""
    rng = np.random.default_rng(4)
    ctrl = S0Homing(S0Params(folded=False))
    for k in range(200):
        raw = (5 + rng.normal(0, 0.5 + (k % 7) * 0.2), -3 + rng.normal(0, 0.3))
        buffer = np.array(ctrl._raw) if ctrl._raw else np.zeros((0, 2))
        if len(buffer) >= 5:
            z = np.abs(np.array(raw) - buffer.mean(axis=0)) / np.maximum(buffer.std(axis=0), 1e-3)
            assert ctrl._is_outlier(raw) == bool(z.max() > 1.645)
        ctrl.on_reading(0.1 * k, Pose(0.01 * k, 0, 0), math.atan2(raw[1], raw[0] - 0.01 * k),
                        math.hypot(raw[0] - 0.01 * k, raw[1]))


def test_ray_fusion_is_ours_and_off_restores_the_hybrid() -> None:
    target = (4.0, 1.0)
    path = [Pose(0.03 * k, 0.25 * k / 130, 0.0) for k in range(130)]
    reports = {}
    for fusion in (False, True):
        ctrl = S0Homing(S0Params(folded=False, k=0.8, ray_fusion=fusion, robust_fit=False))
        rng = np.random.default_rng(2)
        for k, pose in enumerate(path):
            rel = math.atan2(target[1] - pose.y, target[0] - pose.x) + math.radians(rng.uniform(-20, 20))
            d = max(math.dist(target, (pose.x, pose.y)) * (1 + rng.uniform(-0.2, 0.2)) + rng.uniform(-1, 1), 0.05)
            ctrl.on_reading(0.1 * k, pose, rel, d)
        reports[fusion] = ctrl.reported
        if not fusion:
            assert ctrl.reported == ctrl.g_p  # the paper's report: the hybrid's parallax goal
    assert reports[True] != reports[False]


def test_velocity_law_eq15() -> None:
    ctrl = S0Homing(S0Params(v_max=0.6, k_stop=100.0))
    ctrl.phase, ctrl.reported = "homing", np.array([10.0, 0.0])
    assert ctrl.decide(Pose(0, 0, 0)).v == pytest.approx(0.6)
    assert ctrl.decide(Pose(0, 0, math.pi / 4)).v == pytest.approx(0.3)
    behind = ctrl.decide(Pose(0, 0, math.pi))
    assert behind.v == 0.0 and abs(behind.w) > 0


def test_mounting_conversions() -> None:
    assert math.degrees(Mounting().to_robot(-30)) == pytest.approx(30)  # board: left is negative
    assert math.degrees(Mounting(upside_down=True).to_robot(-30)) == pytest.approx(-30)
    assert math.degrees(Mounting(yaw_offset_deg=90).to_robot(0)) == pytest.approx(90)


def test_config_default_and_errors(tmp_path: Path) -> None:
    path = tmp_path / "robot.toml"
    path.write_text(DEFAULT_TOML)
    assert load_config(path) == Config()
    path.write_text("[s0]\nv_max = 0.5\n[loop]\nstale_timeout_s = 0.3\n")
    cfg = load_config(path)
    assert cfg.s0.v_max == 0.5 and cfg.loop.stale_timeout_s == 0.3
    path.write_text("[s0]\nvmax = 1\n")
    with pytest.raises(ConfigError, match="unknown keys \\['vmax'\\]"):
        load_config(path)
    path.write_text("[motors]\n")
    with pytest.raises(ConfigError, match="unknown sections"):
        load_config(path)


# -- closed loop through ptys in lockstep ---------------------------------------------------
async def closed_loop(tmp_path: Path, target: tuple[float, float], seed: int = 1, faults: list[str] = (),
                      config: Config = Config(), capture: bool = False, truth: io.StringIO | None = None):
    scenario = load("s0-open", seed=seed, target=target)
    em = Emulator(scenario, transport="pty", seed=seed, lockstep=True, link_dir=tmp_path,
                  faults=[Fault.parse(f) for f in faults], lockstep_timeout=2.0, truth=truth)
    await em.start()
    world = asyncio.create_task(em.run())
    writer = CaptureWriter(tmp_path / "run.pcapng") if capture else None
    taps = [writer.tap] if writer else []
    base, aoa_port = HostPort(str(tmp_path / "base"), taps=taps), HostPort(str(tmp_path / "aoa"), taps=taps)
    if writer:
        writer.describe(base.name, kind="base")
        writer.describe(aoa_port.name, kind="xplr-aoa")
    out = io.StringIO()
    loop = loop_on("aoa", base, aoa_port, config.for_lockstep(), RunLog(out))
    aoa = loop.sensors[0]
    try:
        outcome = await asyncio.wait_for(loop.run(), 90)
    finally:
        world.cancel()
        await asyncio.gather(world, return_exceptions=True)
        await em.close()
        if writer:
            writer.close()
    robot = em.world.robot
    error = math.hypot(robot.x - target[0], robot.y - target[1])
    return outcome, error, [json.loads(line) for line in out.getvalue().splitlines()], em, aoa


@pytest.mark.parametrize(("seed", "target"), [(1, (6.0, 4.0)), pytest.param(2, (-7.0, 3.0), marks=pytest.mark.slow),
                                            (3, (-5.0, -8.0)), pytest.param(4, (8.0, -6.0), marks=pytest.mark.slow)])
async def test_s0_reaches_the_tag_in_every_quadrant(tmp_path: Path, seed: int, target) -> None:
    outcome, error, log, _, _ = await closed_loop(tmp_path, target, seed)
    assert outcome.arrived and error < 1.0  # S0's success criterion
    assert any(e["kind"] == "command" and e["note"] == "turning to tell front from back" for e in log)


async def test_killed_angle_stream_stops_the_robot_within_the_stale_timeout(tmp_path: Path) -> None:
    config = replace(Config(), loop=replace(LoopSettings(), max_time_s=6.0))
    outcome, _, log, em, _ = await closed_loop(tmp_path, (9.0, 0.5), faults=["unplug@aoa:at=3,for=100"], config=config)
    assert not outcome.arrived and outcome.reason == "time limit" and outcome.stale_stops >= 1
    # one stop after the unplug at robot time 3, never lifted (a pty may also deliver the first
    # angles late enough for a stop at start: its bytes cross the kernel on wall time)
    events = [e for e in log if e["kind"] == "event" and e["t"] >= 3.0]
    stops = [e for e in events if e["what"] == "aoa stale: stop"]
    assert len(stops) == 1 and not any(e["what"] == "aoa fresh again: resume" for e in events)
    last_reading = max(e["t"] for e in log if e["kind"] == "measurement")
    stop = stops[0]
    assert stop["t"] - last_reading <= config.loop.stale_timeout_s + config.loop.control_period_s + 1e-6
    after = [e for e in log if e["kind"] == "command" and e["t"] > stop["t"]]
    assert after and all(e["v"] == 0 and e["w"] == 0 for e in after)
    assert em.device("base").firmware.v == 0.0


async def test_unplug_mid_run_stops_reconnects_resumes_and_arrives(tmp_path: Path) -> None:
    # unplugged for 2 s of robot time, four stale timeouts: no reconnect can beat the replug,
    # however the host's wall-clock back-off falls against lockstep time
    outcome, error, log, _, aoa = await closed_loop(tmp_path, (8.0, 2.0), faults=["unplug@aoa:at=3,for=2"])
    assert outcome.arrived and error < 1.0
    assert outcome.stale_stops >= 1 and aoa.counters["reconnects"] == 1
    assert any(e["kind"] == "event" and e["what"] == "aoa fresh again: resume" for e in log)


async def test_replay_reproduces_estimates_and_commands_exactly(tmp_path: Path) -> None:
    outcome, _, live, _, _ = await closed_loop(tmp_path, (5.0, -3.0), capture=True)
    interfaces, packets, _ = load_capture(tmp_path / "run.pcapng")
    sequencer = Sequencer({iface.name: packets[i] for i, iface in enumerate(interfaces)})
    ports = {recorded_kind(i).name: ReplayPort(i.name, packets[n], sequencer=sequencer) for n, i in enumerate(interfaces)}
    out = io.StringIO()
    replayed = await asyncio.wait_for(
        loop_on("aoa", ports["base"], ports["xplr-aoa"], Config().for_lockstep(), RunLog(out)).run(), 60)
    assert replayed.arrived == outcome.arrived
    assert [json.loads(line) for line in out.getvalue().splitlines()] == live


async def closed_loop_scenario(scenario: str | Scenario, seed: int, config: Config = Config()):
    """Closed loop on a preset (or a scenario) with its own target, in lockstep on the emulator's
    in-process byte pipe (as campaigns run: the same bytes whatever the machine's load); the
    controller follows the scenario's sensor (XPLR-AOA -> S0, AT86RF212 node -> S2)."""
    sc = load(scenario, seed=seed) if isinstance(scenario, str) else scenario
    config = config.for_lockstep()
    em = Emulator(sc, transport="pipe", seed=seed, lockstep=True, lockstep_timeout=30.0)
    await em.start()
    world = asyncio.create_task(em.run())
    out = io.StringIO()
    names = {d.name for d in sc.devices}

    def port(name: str) -> PipePort:
        return PipePort(name, em.device(name).link.host)

    base = port("base")
    target = sc.world.targets[0].position
    if "ble" in names:  # S3: a goal in the beacons' frame
        config = replace(config, trilat=replace(config.trilat, anchors={t.id: list(t.position) for t in sc.world.targets},
                                                goal=[4.0, 4.0]))
        loop = loop_on("trilat", base, port("ble"), config, RunLog(out))
        target = (4.0, 4.0)
    elif "dock_aoa" in names:
        loop = loop_on("dock", base, port("dock_aoa"), config, RunLog(out))
    elif "aoa" in names:
        loop = loop_on("aoa", base, port("aoa"), config, RunLog(out))
    else:
        loop = loop_on("rss", base, port("rss"), config, RunLog(out))
    try:
        outcome = await asyncio.wait_for(loop.run(), 120)
    finally:
        world.cancel()
        await asyncio.gather(world, return_exceptions=True)
        await em.close()
    error = math.hypot(em.world.robot.x - target[0], em.world.robot.y - target[1])
    return outcome, error, [json.loads(line) for line in out.getvalue().splitlines()]


@pytest.mark.parametrize("seed", [3, 6])
async def test_s3_on_the_esp32_scanner_never_stops_for_stale_data(seed: int) -> None:
    """The ESP32 scanner listens all the time, so the four beacons' readings never stop for the
    loop's stale bound: no stale-data stop. With the 50 % duty-cycled scan the emulator keeps as
    a fault option, the same seed stops the robot (the gap the budget bench saw). Without the
    survey at the goal (tests/test_s3_survey.py): it only makes the runs longer."""
    unsurveyed = replace(Config(), trilat=replace(TrilatParams(), survey_m=0.0))
    outcome, _, log = await closed_loop_scenario("s3-arena", seed, unsurveyed)
    heard = [r["t"] for r in log if r["kind"] == "measurement"]
    assert outcome.stale_stops == 0 and max(np.diff(heard)) < Config().loop.stale_timeout_s
    duty_cycled = load("s3-arena", seed=seed)
    next(d for d in duty_cycled.devices if d.name == "ble").options.update(scan_interval_ms=100, scan_window_ms=50)
    outcome, _, _ = await closed_loop_scenario(duty_cycled, seed, unsurveyed)
    assert outcome.stale_stops >= 1


def test_esp32_scan_options_are_checked() -> None:
    sc = load("s3-arena", seed=1)
    next(d for d in sc.devices if d.name == "ble").options.update(scan_interval_ms=100, scan_window_ms=150)
    with pytest.raises(ScenarioError, match=r"\[devices.ble\] needs 2.5 <= scan_window_ms <= scan_interval_ms"):
        Emulator(sc, transport="pipe", seed=1)


async def test_in_process_lockstep_result_does_not_depend_on_the_hosts_awaits(monkeypatch) -> None:
    """The emulator lets an in-process host settle after every step, so a host that takes
    more awaits per reading (a slower machine's scheduling, a refactor) gets the same run:
    the same log, line for line, and the same final pose."""
    from rfhoming.host.drivers.common import BoundedStream

    quick = await closed_loop_scenario("s0-open", 3)
    get = BoundedStream.get

    async def slow_get(self):
        for _ in range(3):
            await asyncio.sleep(0)
        return await get(self)

    monkeypatch.setattr(BoundedStream, "get_nowait", lambda self: None)  # every item through the slow path
    monkeypatch.setattr(BoundedStream, "get", slow_get)
    slow = await closed_loop_scenario("s0-open", 3)
    assert quick[0].arrived and len(quick[2]) > 100
    assert slow[2] == quick[2] and slow[1] == quick[1]


# -- the commands ---------------------------------------------------------------------------
@pytest.mark.slow
def test_demo_command_succeeds_and_writes_its_files(tmp_path: Path) -> None:
    done = subprocess.run([sys.executable, "-m", "rfhoming", "demo", "--json", "--out", str(tmp_path)],
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    summary = json.loads(done.stdout)
    assert summary["success"] and summary["final_position_error_m"] < 1.0
    for name in ("trajectory.png", "capture.pcapng", "run.jsonl", "truth.jsonl"):
        assert (tmp_path / name).stat().st_size > 0
    assert (tmp_path / "trajectory.png").read_bytes()[:4] == b"\x89PNG"


def test_config_command() -> None:
    done = subprocess.run([sys.executable, "-m", "rfhoming", "config", "--print-default"], capture_output=True, text=True, timeout=60)
    assert done.returncode == 0 and done.stdout == DEFAULT_TOML


@pytest.mark.slow
async def test_dead_odometry_is_noticed_and_a_stop_sent(tmp_path: Path) -> None:
    scenario = load("s0-open", seed=5, target=(9.0, 0.0))
    em = Emulator(scenario, transport="pty", seed=5, speed=4.0, link_dir=tmp_path,
                  faults=[Fault.parse("unplug@base:at=3,for=100")])
    await em.start()
    world = asyncio.create_task(em.run())
    out = io.StringIO()
    loop = loop_on("aoa", HostPort(str(tmp_path / "base")), HostPort(str(tmp_path / "aoa")), Config(), RunLog(out))
    base = loop.base
    stops: list[str] = []  # why each stop was sent: what the run log said last
    send_stop = base.stop

    def stop() -> bool:
        events = [json.loads(line) for line in out.getvalue().splitlines() if '"event"' in line]
        stops.append("cancelled" if asyncio.current_task().cancelling() else
                     events[-1]["what"] if events else "connect")
        return send_stop()

    base.stop = stop
    with pytest.raises(asyncio.TimeoutError):  # no odometry, no robot time: the loop waits, stopped
        await asyncio.wait_for(loop.run(), 2.5)
    world.cancel()
    await asyncio.gather(world, return_exceptions=True)
    await em.close()
    # the stops on connect and on cancellation do not count: the watchdog's own stop must be there
    assert stops.count("odometry stale: stop") == 1 and stops[0] == "connect" and stops[-1] == "cancelled"


async def test_base_reset_mid_run_is_reanchored_and_the_loop_keeps_going(tmp_path: Path) -> None:
    """reboot@base restarts the base's t_us at 0: the loop must neither freeze (lockstep would
    time out, waiting for commands) nor lose its fail-safes; it logs the reset and arrives."""
    outcome, error, log, em, _ = await closed_loop(tmp_path, (7.0, 3.0), faults=["reboot@base:at=4"])
    resets = [e for e in log if e["kind"] == "event" and e["what"] == "base clock reset: re-anchored"]
    assert len(resets) == 1 and resets[0]["base_clock_now"] < 0.1 < 3.9 < resets[0]["base_clock_before"]
    assert em.counters["lockstep_timeouts"] == 0
    commands = [e["t"] for e in log if e["kind"] == "command"]
    assert max(b - a for a, b in zip(commands, commands[1:])) <= 0.1 + 0.02 + 1e-6  # no gap in control
    assert outcome.arrived and error < 1.0


def test_base_reboot_restarts_its_clock() -> None:
    from rfhoming.firmware.robot_base import RobotBaseFirmware
    from rfhoming.protocol.frames import FrameDecoder, Odometry

    fw = RobotBaseFirmware()
    for k in range(0, 3_000_000, 10_000):
        fw.step(k)
    fw.reset(3_000_000)
    for k in range(3_000_000, 3_100_000, 10_000):
        fw.step(k)
    stamps = [r.t_us for r in FrameDecoder().feed(fw.read()) if isinstance(r, Odometry)]
    after = stamps[stamps.index(max(stamps)) + 1:]
    assert max(stamps) >= 2_980_000 and after and after[0] == 0 and after == sorted(after) and after[-1] < 100_000


def driven_after(truth: str, t_from: float) -> tuple[float, float]:
    """From the emulator's truth lines: (speed at t_from, path length driven from t_from on)."""
    pts = [(r["t"], r["robot"]["x"], r["robot"]["y"]) for r in map(json.loads, truth.splitlines()) if "robot" in r]
    i = next(k for k, p in enumerate(pts) if p[0] >= t_from - 1e-9)
    speed = math.hypot(pts[i][1] - pts[i - 1][1], pts[i][2] - pts[i - 1][2]) / (pts[i][0] - pts[i - 1][0])
    return speed, sum(math.hypot(b[1] - a[1], b[2] - a[2]) for a, b in zip(pts[i:], pts[i + 1:]))


async def test_stopping_distance_on_stale_data_is_bounded_in_truth() -> None:
    """The angle stream dies while the robot drives at full speed: measured on the emulator's
    true pose (not the loop's log), it comes to rest within 0.25 m of where the data ended.
    In-process byte pipe: the machine's load cannot delay one device's bytes against the other's."""
    from rfhoming.campaigns.closed_loop import PipePort

    truth = io.StringIO()
    em = Emulator(load("s0-open", seed=1, target=(12.0, 0.5)), transport="pipe", seed=1, lockstep=True,
                  lockstep_timeout=2.0, truth=truth, faults=[Fault.parse("unplug@aoa:at=5,for=100")])
    await em.start()
    world = asyncio.create_task(em.run())
    config = Config().for_lockstep()
    config = replace(config, loop=replace(config.loop, max_time_s=8.0))
    out = io.StringIO()
    base, aoa = PipePort("base", em.device("base").link.host), PipePort("aoa", em.device("aoa").link.host)
    try:
        outcome = await asyncio.wait_for(loop_on("aoa", base, aoa, config, RunLog(out)).run(), 60)
    finally:
        world.cancel()
        await asyncio.gather(world, return_exceptions=True)
        await em.close()
    speed, driven = driven_after(truth.getvalue(), 5.0)
    assert speed > 0.6  # it was at (nearly) full speed when the data ended
    assert driven <= 0.25
    assert em.device("base").firmware.v == 0.0 and outcome.stale_stops == 1
    log = [json.loads(line) for line in out.getvalue().splitlines()]
    assert any(e["kind"] == "event" and e["what"] == "brake mode on" and 5.0 < e["t"] < 5.3 for e in log)


@pytest.mark.parametrize("brake", [False, True])
def test_base_brake_mode_sheds_speed_at_its_emergency_deceleration(brake: bool) -> None:
    from rfhoming.firmware.robot_base import BaseLimits, RobotBaseFirmware
    from rfhoming.protocol.frames import NodeCommand, VelocityCommand, encode_frame

    fw = RobotBaseFirmware()
    fw.receive(encode_frame(VelocityCommand(0, 1, 0, 700, 0, 60_000)))
    for k in range(0, 1_000_000, 10_000):
        fw.step(k)
    assert fw.v == pytest.approx(0.7)
    fw.receive(encode_frame(NodeCommand(0, 2, 0, 5, bytes([int(brake)]))) + encode_frame(VelocityCommand(0, 3, 0, 0, 0, 60_000)))
    for k in range(1_000_000, 1_100_000, 10_000):  # 0.1 s
        fw.step(k)
    a = BaseLimits().a_emergency if brake else BaseLimits().a_max
    assert fw.v == pytest.approx(max(0.0, 0.7 - a * 0.1))


def _preliminary_after_fixes(ranges: list[float | None]) -> str:
    """The preliminary system's decision with the emitter dead ahead and one scan of ``ranges``
    (±90°), after enough fixes to home."""
    from rfhoming.host.drivers.robot_base import Scan
    from rfhoming.host.drivers.rss import AntennaPowers
    from rfhoming.host.homing.s2_rss import RssController, S2Params

    c = RssController(S2Params(motion="preliminary", peak_gain_db=0.0, spin_calibration=False))  # no first turn: the rules at once
    for k in range(12):  # x1 strongest, x2 weakest, sides equal: ahead, about 3 m
        c.on_input(0.05 * k, Pose(0.0, 0.0, 0.0), AntennaPowers(0.05 * k, 1, k, (-50.0, -70.0, -60.0, -60.0)))
    c.on_scan(Scan(0.0, -math.pi / 2, math.pi / (len(ranges) - 1), ranges))
    return c.decide(Pose(0.0, 0.0, 0.0)).note


def test_preliminary_20_cm_are_from_the_robots_body() -> None:
    free = [None] * 181
    assert "forward" in _preliminary_after_fixes(free)
    ahead = free[:]
    ahead[90] = 0.40  # 0.15 m from a 0.25 m body: inside S2's 20 cm, though 0.4 m from the scanner
    assert "obstacle" in _preliminary_after_fixes(ahead)
    ahead[90] = 0.50
    assert "forward" in _preliminary_after_fixes(ahead)
    beside = free[:]
    beside[0] = 0.27  # touching on the right, outside the ±30° ahead
    assert "obstacle" in _preliminary_after_fixes(beside)
