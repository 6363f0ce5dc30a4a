"""The figure of docs/usage.md section 7, "The frames, read back": two MCAP recordings read
with rosbags alone (not rfhoming's objects) -- each one's TF tree as its /tf and /tf_static
say, and the run drawn through those transforms: S1's docking (the robot's path in odom, the
station where odom -> dock_station puts it, the station's bearings to the robot drawn in its
frame) and fixed anchors (the anchors where map -> anchor_<id> puts them, their bearings to the
tags, the robot's path through map -> odom -> base_link).

    python bench/frames_figure.py [-o docs/results/mcap-frames.png] [--s1 S1.mcap] [--anchors ANCHORS.mcap]

Without --s1/--anchors it records them first: ``rfhoming demo --scenario s1-dock --seed 1 --radio ideal`` (S1's own noise, as its figures were taken)
and ``rfhoming run --controller anchors`` on ``rfhoming emulate kit-home --seed 1 --lockstep``.
"""

from __future__ import annotations

import argparse
import json
import math
import signal
import subprocess
import sys
import tempfile
from collections import defaultdict
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from rosbags.highlevel import AnyReader  # noqa: E402
from scipy.spatial.transform import Rotation  # noqa: E402

from rfhoming.host.outputs import save_figure  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
RFHOMING = [sys.executable, "-m", "rfhoming"]


def record_s1(tmp: Path) -> Path:
    mcap = tmp / "s1-dock.mcap"
    subprocess.run([*RFHOMING, "demo", "--scenario", "s1-dock", "--seed", "1", "--radio", "ideal", "--out", str(tmp / "s1"),
                    "--mcap", str(mcap), "--json"], check=False, capture_output=True, timeout=300)
    return mcap


def record_anchors(tmp: Path) -> Path:
    links = tmp / "links"
    links.mkdir()
    site = tmp / "site.toml"
    site.write_text((ROOT / "docs" / "sites" / "kit-home.toml").read_text().replace("/tmp/rfhoming-kit/", f"{links}/"))
    mcap = tmp / "anchors.mcap"
    emulator = subprocess.Popen([*RFHOMING, "emulate", "kit-home", "--seed", "1", "--radio", "ideal", "--lockstep", "--link-dir", str(links)],
                                stdout=subprocess.PIPE, text=True)
    try:
        for _ in range(5):
            json.loads(emulator.stdout.readline())
        subprocess.run([*RFHOMING, "run", "--controller", "anchors", "--site", str(site), "--base", f"base:{links}/base",
                        "--mcap", str(mcap)], check=False, capture_output=True, timeout=300)
    finally:
        emulator.send_signal(signal.SIGINT)
        emulator.wait(timeout=30)
    return mcap


class Recording:
    """What rosbags reads from one MCAP: every transform (parent, child, t, xyz, quaternion)
    and the messages of the topics asked for."""

    def __init__(self, path: Path, topics: tuple[str, ...]) -> None:
        self.tf: dict[tuple[str, str], list[tuple[float, np.ndarray, np.ndarray]]] = defaultdict(list)
        self.static: set[tuple[str, str]] = set()
        self.messages: dict[str, list[tuple[float, object]]] = defaultdict(list)
        with AnyReader([path]) as reader:
            for connection, t, raw in reader.messages():
                if connection.topic not in ("/tf", "/tf_static", *topics):
                    continue
                msg = reader.deserialize(raw, connection.msgtype)
                if connection.topic in topics:
                    self.messages[connection.topic].append((t / 1e9, msg))
                    continue
                for tf in msg.transforms:
                    key = (tf.header.frame_id, tf.child_frame_id)
                    tr, q = tf.transform.translation, tf.transform.rotation
                    self.tf[key].append((t / 1e9, np.array([tr.x, tr.y, tr.z]), np.array([q.x, q.y, q.z, q.w])))
                    if connection.topic == "/tf_static":
                        self.static.add(key)

    def parent(self, child: str) -> str | None:
        return next((p for p, c in self.tf if c == child), None)

    def at(self, child: str, t: float) -> tuple[np.ndarray, Rotation] | None:
        """child -> root (map, or odom where no map is above it) at time t: the latest transform
        of each link at or before t (a static one at any time)."""
        xyz, rot = np.zeros(3), Rotation.identity()
        frame = child
        while (parent := self.parent(frame)) is not None:
            samples = self.tf[(parent, frame)]
            before = [s for s in samples if s[0] <= t] or ([samples[0]] if (parent, frame) in self.static else [])
            if not before:
                return None
            _, p, q = before[-1]
            r = Rotation.from_quat(q)
            xyz, rot = p + r.apply(xyz), r * rot
            frame = parent
        return xyz, rot

    def root(self, frame: str) -> str:
        while (parent := self.parent(frame)) is not None:
            frame = parent
        return frame


def draw_tree(ax: plt.Axes, rec: Recording, title: str) -> None:
    children: dict[str, list[str]] = defaultdict(list)
    for parent, child in sorted(rec.tf):
        children[parent].append(child)
    roots = sorted({p for p, _ in rec.tf} - {c for _, c in rec.tf})
    place: dict[str, tuple[float, float]] = {}
    leaves = [0]

    def lay(frame: str, depth: int) -> float:
        kids = children.get(frame, [])
        if not kids:
            y = leaves[0]
            leaves[0] += 1
        else:
            y = float(np.mean([lay(k, depth + 1) for k in kids]))
        place[frame] = (depth, y)
        return y

    for r in roots:
        lay(r, 0)
    for (parent, child), samples in rec.tf.items():
        (x0, y0), (x1, y1) = place[parent], place[child]
        static = (parent, child) in rec.static
        ax.annotate("", (x1, -y1), (x0, -y0), arrowprops={"arrowstyle": "-|>", "color": "0.4" if static else "tab:red",
                                                       "lw": 1.2, "shrinkA": 22, "shrinkB": 26})
        label = "static" if static else f"/tf x{len(samples)}"
        ax.text((x0 + x1) / 2, -(y0 + y1) / 2 + 0.15, label, fontsize=7, ha="center",
                color="0.4" if static else "tab:red")
    for frame, (x, y) in place.items():
        ax.text(x, -y, frame, ha="center", va="center", fontsize=8,
                bbox={"boxstyle": "round", "fc": "lightyellow" if frame in ("map", "odom") else "white", "ec": "0.3"})
    ax.set_xlim(-0.6, max(x for x, _ in place.values()) + 0.6)
    ax.set_ylim(-leaves[0], 1)
    ax.axis("off")
    ax.set_title(title, fontsize=10)


def path_of(rec: Recording, every: float = 0.1) -> np.ndarray:
    times = [t for t, _, _ in rec.tf[("odom", "base_link")]]
    points, last = [], -math.inf
    for t in times:
        if t - last >= every and (pose := rec.at("base_link", t)) is not None:
            points.append(pose[0][:2])
            last = t
    return np.array(points)


def ray(ax: plt.Axes, rec: Recording, frame: str, t: float, a: float, length: float, color: str) -> None:
    """A board's bearing (an AoaAngle's azimuth_rad: REP 103, about its frame's z) from its frame."""
    pose = rec.at(frame, t)
    if pose is None:
        return
    tip = pose[0] + pose[1].apply([length * math.cos(a), length * math.sin(a), 0.0])
    ax.plot([pose[0][0], tip[0]], [pose[0][1], tip[1]], color=color, lw=0.6, alpha=0.5)


def axes_of(ax: plt.Axes, rec: Recording, frame: str, t: float, label: str) -> None:
    pose = rec.at(frame, t)
    if pose is None:
        return
    (x, y, _), r = pose
    d = r.apply([0.5, 0.0, 0.0])
    ax.annotate("", (x + d[0], y + d[1]), (x, y), arrowprops={"arrowstyle": "->", "color": "k", "lw": 1.6})
    ax.plot(x, y, "ks", ms=5)
    ax.text(x + 0.08, y + 0.12, label, fontsize=8)


def draw_s1(ax: plt.Axes, rec: Recording) -> None:
    path = path_of(rec)
    ax.plot(path[:, 0], path[:, 1], color="tab:blue", lw=1.5, label="base_link in odom (/tf)")
    angles = rec.messages["/rfhoming/aoa/angle"]
    for t, msg in angles[::8]:
        robot = rec.at("base_link", t)
        station = rec.at("dock_station", t)
        if robot is not None and station is not None:
            ray(ax, rec, "dock_station", t, msg.azimuth_rad, float(np.linalg.norm(robot[0][:2] - station[0][:2])),
                "tab:orange")
    end = max(t for t, _, _ in rec.tf[("odom", "dock_station")])
    axes_of(ax, rec, "dock_station", end, "dock_station (last fit)")
    ax.plot([], [], color="tab:orange", lw=0.6, label="station's bearings, in dock_station")
    ax.set_xlim(-2.0, 3.0)
    ax.set_aspect("equal")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7, loc="lower right")
    ax.set_xlabel("odom x (m)")
    ax.set_ylabel("odom y (m)")
    ax.set_title("S1 docking, drawn through the recording's frames", fontsize=10)


def draw_anchors(ax: plt.Axes, rec: Recording) -> None:
    path = path_of(rec)
    ax.plot(path[:, 0], path[:, 1], color="tab:blue", lw=1.5, label="base_link in map (map -> odom -> base_link)")
    anchors = sorted(c for p, c in rec.tf if p == "map" and c.startswith("anchor_"))
    angles = rec.messages["/rfhoming/aoa/angle"]
    times = [t for t, _ in angles]
    snapshot = times[len(times) // 2]
    robot = rec.at("base_link", snapshot)
    for frame in anchors:
        axes_of(ax, rec, frame, snapshot, frame.removeprefix("anchor_")[-4:])
    latest = {(m.header.frame_id, m.instance_id): (t, m) for t, m in angles if snapshot - 0.5 <= t <= snapshot}
    for t, msg in latest.values():  # one instant: each anchor's latest bearing to each tag
        ray(ax, rec, msg.header.frame_id, t, msg.azimuth_rad, 14.0, "tab:orange")
    if robot is not None:
        ax.plot(*robot[0][:2], "o", color="tab:blue", ms=6)
    ax.plot([], [], color="tab:orange", lw=0.6, label=f"bearings at t = {snapshot:.1f} s, in anchor_<id>")
    ax.set_xlim(-1, 13)
    ax.set_ylim(-1, 7)
    ax.set_aspect("equal")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7, loc="upper left")
    ax.set_xlabel("map x (m)")
    ax.set_ylabel("map y (m)")
    ax.set_title("fixed anchors (kit-home), drawn through the recording's frames", fontsize=10)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("-o", "--output", type=Path, default=ROOT / "docs" / "results" / "mcap-frames.png")
    ap.add_argument("--s1", type=Path, help="an S1 recording (default: record one)")
    ap.add_argument("--anchors", type=Path, help="a fixed-anchors recording (default: record one)")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        s1 = Recording(args.s1 or record_s1(Path(tmp)), ("/rfhoming/aoa/angle",))
        anchors = Recording(args.anchors or record_anchors(Path(tmp)), ("/rfhoming/aoa/angle",))
    fig, ax = plt.subplots(2, 2, figsize=(13, 9.5), gridspec_kw={"width_ratios": [1, 1.5]})
    draw_tree(ax[0, 0], s1, "S1 docking: the TF tree in its MCAP")
    draw_s1(ax[0, 1], s1)
    draw_tree(ax[1, 0], anchors, "fixed anchors: the TF tree in its MCAP")
    draw_anchors(ax[1, 1], anchors)
    fig.suptitle("Read back with rosbags from the MCAP files alone: parent -> child (red: /tf, grey: /tf_static)",
                 fontsize=11)
    fig.tight_layout()
    args.output.parent.mkdir(parents=True, exist_ok=True)
    save_figure(fig, args.output, dpi=110)  # OUTPUT.part, renamed when whole: a failed plot leaves the old one
    print(json.dumps({"figure": str(args.output), "s1_transforms": {f"{p}->{c}": len(v) for (p, c), v in s1.tf.items()},
                      "anchors_transforms": {f"{p}->{c}": len(v) for (p, c), v in anchors.tf.items()}}))


if __name__ == "__main__":
    main()
