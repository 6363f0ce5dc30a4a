"""S1 (Electronics 2026): docking trials from random starts, with and without the final
alignment onto the station's fitted axis."""

from __future__ import annotations

import math
from dataclasses import replace
from typing import Any

import numpy as np

from rfhoming.campaigns import closed_loop
from rfhoming.campaigns.report import figure, mean, save, table
from rfhoming.campaigns.runner import Campaign, Job, Report
from rfhoming.emulator.scenario import load
from rfhoming.host.homing.config import Config

PAPER = {"docked_pct": 100, "trials": 5, "final_error_m": 0.48, "heading_error_deg": 12.5}
"""S1's trial: final pose (0.5149, 3.1324, 102.49°) for the station at (0.4, 3.6, 90°)."""
MODES = {"paper": False, "aligned": True}  # S1Params.align


def trial(mode: str, start: tuple[float, float, float], seed: int) -> dict[str, Any]:
    """Dock from ``start``; errors against the docked pose, ``standoff_m`` in front of the station."""
    config = replace(Config(), s1=replace(Config().s1, align=MODES[mode]))
    scenario = load("s1-dock", seed=seed)
    scenario.world.robot.x, scenario.world.robot.y, scenario.world.robot.theta = start
    run = closed_loop.run(scenario, config, seed)
    station = scenario.world.targets[0]
    standoff = config.s1.standoff_m
    docked = (station.position[0] - standoff * math.cos(station.heading),
              station.position[1] - standoff * math.sin(station.heading))
    x, y, theta = run.robot
    return {"mode": mode, "start": [round(v, 3) for v in start], "docked": run.outcome.arrived,
            "time_s": round(run.outcome.robot_time_s, 2), "final_error_m": round(math.dist((x, y), docked), 4),
            "heading_error_deg": round(abs(math.degrees(math.remainder(theta - station.heading, 2 * math.pi))), 2)}


def jobs(runs: int, seed: int) -> list[Job]:
    """Random starts 2.4–3.4 m in front of the station (inside S1's docking stage, which begins at
    −73 dBm, about 3.8 m here), up to 0.8 m off its axis and ±17° off its heading."""
    rng = np.random.default_rng([seed, 0x51])
    starts = [(0.4 + float(rng.uniform(-0.8, 0.8)), float(rng.uniform(0.2, 1.2)),
               math.pi / 2 + float(rng.uniform(-0.3, 0.3))) for _ in range(runs)]
    return [Job(i * len(MODES) + j, "rfhoming.campaigns.s1:trial", {"mode": mode, "start": start, "seed": seed * 100_000 + i})
            for i, start in enumerate(starts) for j, mode in enumerate(MODES)]


def report(rows: list[dict[str, Any]]) -> Report:
    summary = {}
    lines = [["paper (one trial shown of 5)", PAPER["docked_pct"], None, PAPER["final_error_m"], None,
              PAPER["heading_error_deg"], None]]
    for mode in MODES:
        r = [row for row in rows if row["mode"] == mode]
        s = {"trials": len(r), "docked_pct": round(100 * sum(x["docked"] for x in r) / len(r), 1),
             "time_s": mean(r, "time_s", 2), "final_error_m": mean(r, "final_error_m"),
             "max_final_error_m": round(max(x["final_error_m"] for x in r), 3),
             "heading_error_deg": mean(r, "heading_error_deg", 2),
             "max_heading_error_deg": round(max(x["heading_error_deg"] for x in r), 2)}
        summary[mode] = s
        label = "ours, S1's rule" if mode == "paper" else "ours, + final alignment"
        lines.append([f"{label} ({s['trials']} trials)", s["docked_pct"], s["time_s"], s["final_error_m"],
                      s["max_final_error_m"], s["heading_error_deg"], s["max_heading_error_deg"]])
    md = table(["source", "docked %", "time s", "final error m (mean)", "max", "heading error ° (mean)", "max"], lines)

    def plot(path):
        fig, axes = figure(path, 2)
        for mode in MODES:
            r = [row for row in rows if row["mode"] == mode]
            axes[0].hist([x["final_error_m"] for x in r], bins=15, alpha=0.6, label=mode)
            axes[1].hist([x["heading_error_deg"] for x in r], bins=15, alpha=0.6, label=mode)
        axes[0].axvline(PAPER["final_error_m"], color="k", ls="--", label="paper trial")
        axes[1].axvline(PAPER["heading_error_deg"], color="k", ls="--", label="paper trial")
        axes[0].set_title("final position error (m)")
        axes[1].set_title("final heading error (°)")
        axes[0].legend()
        save(fig, path)

    return Report(summary, md, {"s1-dock.png": plot})


CAMPAIGN = Campaign("s1-dock", "S1 docking from random starts, S1's rule and with final alignment",
                    "trials (each run in both modes)", 50, jobs, report)
