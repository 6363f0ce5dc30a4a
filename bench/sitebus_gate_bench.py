"""The site worker's gate on inconsistent fixes (host/estimation/batch.py, INCONSISTENT_CHI2_PER_DOF):
how far below it honest fixes stay, and what a rogue gateway does to a site with it.

    python bench/sitebus_gate_bench.py [--seconds 30] [--seeds 3] [--json]

Per emulated site (emulator/site.py: anchors on a 6 m grid under a 6 m ceiling, 2 degree angle
noise, each board with its own bias; 0.5 degree by default, 2 degrees in the "biased" rows) and
seed: the batched engine as a worker runs it (tracked, the gate on, a tick every 0.05 s of site
time), fed ``--seconds`` of angles, then as long again with a rogue gateway beside the real ones
sending, for every real event, one of the same anchor and tag with an azimuth of -60 or +60
degrees (as the rogue gateway of a loopback trial). Reported: the quantiles of chi2_per_dof of the honest fixes
and how many of them the gate flagged (false alarms); under the rogue, the share of positions
flagged and the horizontal error against the truth of those not flagged, beside the honest
phase's. In-process, no broker: the engine's answers depend on the events alone.
"""

from __future__ import annotations

import argparse
import json

import numpy as np

from rfhoming.emulator.site import SiteScenario
from rfhoming.host.estimation.batch import INCONSISTENT_CHI2_PER_DOF, BatchLocator
from rfhoming.host.site import Anchor, Site

TICK_S = 0.05


def _site(sc: SiteScenario) -> Site:
    return Site("bench", tuple(Anchor(a.name, a.id, None, a.position, 0.0, a.pitch_deg) for a in sc.anchors),
                sigma_deg=sc.sigma_deg)


def _phase(sc: SiteScenario, loc: BatchLocator, t: float, seconds: float, rogue: np.random.Generator | None
           ) -> tuple[float, list[tuple[float, bool, float]]]:
    """Feed and tick ``seconds`` from site time ``t``: (the end, [(chi2_per_dof, flagged, error m)])."""
    out = []
    tag_row = {tag: k for k, tag in enumerate(sc.tags)}
    for _ in range(round(seconds / TICK_S)):
        rows = sorted(row for rows in sc.events(t, t + TICK_S).values() for row in rows)
        if rogue is not None:
            fake = [(tt, a, tag, float(rogue.choice([-60, 60])), el) for tt, a, tag, _, el in rows]
            rows = sorted(rows + fake)
        loc.feed(rows)
        t += TICK_S
        for f in loc.tick(t, only_new=True):
            truth = sc.truth(t, np.array([tag_row[f.tag]]))[0]
            out.append((f.quality, f.inconsistent, float(np.hypot(*(f.fix.point[:2] - truth[:2])))))
    return t, out


def run(seconds: float, seeds: int) -> list[dict[str, object]]:
    rows = []
    for label, bias in (("site-16x40", 0.5), ("site-16x40 biased", 2.0)):
        for seed in range(1, seeds + 1):
            sc = SiteScenario(16, 40, seed=seed, clock_spread_s=0.0, bias_deg=bias)
            loc = BatchLocator(_site(sc), track=True, gate=INCONSISTENT_CHI2_PER_DOF)
            t, honest = _phase(sc, loc, 100.0, seconds, None)
            _, rogue = _phase(sc, loc, t, seconds, np.random.default_rng(seed))
            q = np.array([h[0] for h in honest])
            kept = [r[2] for r in rogue if not r[1]]
            rows.append({
                "site": label, "seed": seed, "honest_positions": len(honest),
                "chi2_per_dof_p50": round(float(np.median(q)), 3),
                "chi2_per_dof_p99": round(float(np.quantile(q, 0.99)), 3),
                "chi2_per_dof_p999": round(float(np.quantile(q, 0.999)), 3),
                "chi2_per_dof_max": round(float(q.max()), 3),
                "honest_flagged": sum(h[1] for h in honest),
                "honest_error_m_p50": round(float(np.median([h[2] for h in honest])), 3),
                "rogue_positions": len(rogue), "rogue_flagged": sum(r[1] for r in rogue),
                "rogue_chi2_per_dof_max": round(max(r[0] for r in rogue), 1),
                "rogue_unflagged_error_m_p50": round(float(np.median(kept)), 3) if kept else None,
                "rogue_unflagged_error_m_p90": round(float(np.quantile(kept, 0.9)), 3) if kept else None,
            })
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seconds", type=float, default=30.0, help="site seconds of each phase (default 30)")
    ap.add_argument("--seeds", type=int, default=3, help="seeds per site (default 3)")
    ap.add_argument("--json", action="store_true", help="one JSON object, the rows under \"rows\"")
    args = ap.parse_args()
    rows = run(args.seconds, args.seeds)
    if args.json:
        print(json.dumps({"gate_chi2_per_dof": INCONSISTENT_CHI2_PER_DOF, "tick_s": TICK_S,
                          "seconds": args.seconds, "rows": rows}))
        return
    for r in rows:
        print(" ".join(f"{k}={v}" for k, v in r.items()))


if __name__ == "__main__":
    main()
