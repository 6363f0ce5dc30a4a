"""The figure of docs/estimation.md "Fixed anchors in 3-D": the kit room from above (anchors,
their rays to one tag at one instant, a tag's true path and its tracked positions) and one
anchor from the side (boresight pitch, elevation, the ray down to the tag).

    python bench/locate_figure.py [-o docs/results/locate-geometry.png]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from rfhoming.campaigns.kit import record  # noqa: E402
from rfhoming.host import site as sites  # noqa: E402
from rfhoming.host.locate import Locator  # noqa: E402
from rfhoming.host.outputs import save_figure  # noqa: E402

TAG = "CCF9578E0D8A"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("-o", "--output", type=Path, default=Path("docs/results/locate-geometry.png"))
    args = ap.parse_args()
    site = sites.load("docs/sites/kit-room.toml")
    rec = record(seed=1, duration=20.0)
    loc = Locator(site, reorder_s=0.0)
    out = []
    snapshot = None
    for e in rec.events:
        for p in loc.feed(e):
            out.append(p)
            if snapshot is None and p.tag == TAG and p.t >= 6.0:
                snapshot = (p, loc.rays_at(TAG, p.t)[0])
    fig, (top, side) = plt.subplots(1, 2, figsize=(13, 5.2), gridspec_kw={"width_ratios": [1.4, 1]})
    top.add_patch(plt.Rectangle((0, 0), 12, 6, fill=False, lw=2))
    ts = np.arange(2.0, 20.0, 0.05)
    truth = np.array([rec.truth(TAG, t) for t in ts])
    top.plot(truth[:, 0], truth[:, 1], "k-", lw=1, label="tag's true path")
    track = np.array([p.point for p in out if p.tag == TAG and p.t >= 2.0])
    top.plot(track[:, 0], track[:, 1], ".", ms=3, color="tab:blue", label="tracked positions (10 Hz)")
    assert snapshot is not None
    fix, rays = snapshot
    for a, ray in zip(site.anchors, rays):
        x, y, z = a.position
        yaw = np.radians(a.yaw_deg)
        top.plot(x, y, "s", color="tab:red", ms=9)
        top.annotate("", (x + 0.8 * np.cos(yaw), y + 0.8 * np.sin(yaw)), (x, y),
                     arrowprops={"arrowstyle": "->", "color": "tab:red"})
        top.text(x, y + 0.25, f"{a.name} z={z:g} m", ha="center", fontsize=8)
        r = np.linalg.norm(fix.point - ray.origin) * 1.2
        end = ray.origin + r * ray.direction
        top.plot([x, end[0]], [y, end[1]], "--", color="tab:orange", lw=1)
    top.plot(*fix.point[:2], "o", color="tab:green", ms=8, label=f"fix at t={fix.t:.1f} s (rays dashed)")
    top.set_xlim(-0.8, 12.8)
    top.set_ylim(-0.8, 6.8)
    top.set_aspect("equal")
    top.set_xlabel("x (m)")
    top.set_ylabel("y (m)")
    top.set_title("kit-room from above: 4 wall anchors, boresight arrows")
    top.legend(loc="upper right", fontsize=7)
    # side view of the west anchor: pitch, elevation, the ray
    a = site.anchors[0]
    h = a.position[2]
    pitch = np.radians(a.pitch_deg)
    tag = rec.truth(TAG, fix.t)
    d = np.hypot(tag[0] - a.position[0], tag[1] - a.position[1])
    side.plot([0, d], [h, tag[2]], "--", color="tab:orange", label="ray to the tag")
    side.annotate("", (3 * np.cos(pitch), h + 3 * np.sin(pitch)), (0, h),
                  arrowprops={"arrowstyle": "->", "color": "tab:red"})
    side.text(3 * np.cos(pitch), h + 3 * np.sin(pitch) - 0.35, "boresight x (pitch -20 deg)", fontsize=8,
              color="tab:red")
    side.plot([0, 0], [h - 0.15, h + 0.15], color="tab:red", lw=4)
    side.plot(d, tag[2], "o", color="tab:green")
    side.text(d, tag[2] + 0.12, "tag", ha="center", fontsize=8)
    el = np.degrees(np.arctan2(tag[2] - h, d)) - a.pitch_deg
    side.text(d / 2, h + 0.25, f"elevation = {el:.0f} deg\n(from boresight, + = toward\nthe board's top edge)", fontsize=8)
    side.axhline(0, color="k", lw=1)
    side.set_xlim(-0.3, max(d + 0.5, 3))
    side.set_ylim(-0.2, h + 1.0)
    side.set_aspect("equal")
    side.set_xlabel("horizontal distance (m)")
    side.set_ylabel("z (m)")
    side.set_title(f"{a.name} anchor from the side")
    side.legend(loc="lower left", fontsize=7)
    fig.tight_layout()
    args.output.parent.mkdir(parents=True, exist_ok=True)
    save_figure(fig, args.output, dpi=110)  # OUTPUT.part, renamed when whole: a failed plot leaves the old one
    print(f"wrote {args.output}")


if __name__ == "__main__":
    main()
