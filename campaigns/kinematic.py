"""The idealised S0 simulation: a unicycle with the base's limits, bearings and distances with
S0 Table 2's uniform noise handed straight to the controller (no fold, no codec, no RSSI).

This is the paper's own set-up; the realistic mode runs the same controller through the
emulator and the host stack instead (:mod:`rfhoming.campaigns.closed_loop`).
"""

from __future__ import annotations

import math
from dataclasses import replace
from typing import Any

import numpy as np

from rfhoming.campaigns.closed_loop import ARRIVED_M  # open field: always in the target's line of sight
from rfhoming.emulator import arrival
from rfhoming.emulator.world import Pose as WorldPose
from rfhoming.firmware.robot_base import BaseLimits
from rfhoming.host.estimation.fixed import wrap_rad
from rfhoming.host.homing.s0_aoa import S0Homing, S0Params
from rfhoming.host.homing.types import Pose

LIMITS = BaseLimits()  # the emulated base's speed and acceleration limits
READING_S, CONTROL_S = 0.02, 0.1  # the tag's 50 Hz, the loop's 10 Hz


def _toward(value: float, target: float, step: float) -> float:
    return value + max(-step, min(step, target - value))


def home(target: tuple[float, float], angle_deg: float, distance_rel: float, distance_abs_m: float,
         seed: int, params: S0Params | None = None, max_time_s: float = 180.0,
         reading_s: float = READING_S) -> dict[str, Any]:
    """One idealised homing from (0, 0) facing +x, a reading every ``reading_s``; S0 Table 3's
    metrics."""
    rng = np.random.default_rng(seed)
    s0 = S0Homing(params or replace(S0Params(), folded=False))
    robot = WorldPose(0.0, 0.0, 0.0)
    v = w = 0.0
    cmd_v = cmd_w = 0.0
    travelled, t = 0.0, 0.0
    per_control = max(1, round(CONTROL_S / reading_s))
    goal = None
    arrived = False
    for step in range(int(max_time_s / reading_s)):
        t = step * reading_s
        pose = Pose(robot.x, robot.y, robot.theta)
        d = math.hypot(target[0] - robot.x, target[1] - robot.y)
        bearing = math.atan2(target[1] - robot.y, target[0] - robot.x) - robot.theta
        theta_s = wrap_rad(bearing + math.radians(rng.uniform(-angle_deg, angle_deg)))
        noisy_d = d * (1 + rng.uniform(-distance_rel, distance_rel)) + rng.uniform(-distance_abs_m, distance_abs_m)
        s0.on_reading(t, pose, theta_s, max(noisy_d, 0.05))
        if step % per_control == 0:
            decision = s0.decide(pose)
            goal = decision.goal
            if decision.arrived:
                arrived = True
                break
            cmd_v = max(-LIMITS.v_max, min(LIMITS.v_max, decision.v))
            cmd_w = max(-LIMITS.w_max, min(LIMITS.w_max, decision.w))
        for _ in range(max(1, round(reading_s / READING_S))):  # the robot moves in 20 ms steps
            v = _toward(v, cmd_v, LIMITS.a_max * READING_S)
            w = _toward(w, cmd_w, LIMITS.alpha_max * READING_S)
            x0, y0 = robot.x, robot.y
            robot.advance(v, w, READING_S)
            travelled += math.hypot(robot.x - x0, robot.y - y0)
    straight = math.hypot(robot.x, robot.y)
    final = math.dist((robot.x, robot.y), target)
    return {"arrived": arrived, "success": arrived and arrival.arrived((robot.x, robot.y), target, ARRIVED_M, []), "time_s": round(t, 3),
            "net_velocity_mps": round(straight / t, 4) if t > 0 else None,
            "goal_error_m": None if goal is None else round(math.dist(goal, target), 4),
            "final_error_m": round(final, 4),
            "path_efficiency": round(straight / travelled, 4) if travelled > 0 else None}
