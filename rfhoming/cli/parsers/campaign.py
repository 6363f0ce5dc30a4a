"""``rfhoming campaign``: run a campaign, write its JSON, Markdown table and plots."""

from __future__ import annotations

import argparse
import os

from rfhoming.cli.args import dask_address, output_folder, runs, seed, workers
from rfhoming.cli.parsers import command
from rfhoming.cli.parsers.common import IDEAL, add_radio_option

REGISTRY = {  # name -> "module:attribute", imported only when run
    "s0-table3": "rfhoming.campaigns.s0:TABLE3_CAMPAIGN",
    "s0-house": "rfhoming.campaigns.s0:HOUSE_CAMPAIGN",
    "s1-dock": "rfhoming.campaigns.s1:CAMPAIGN",
    "s2-scenarios": "rfhoming.campaigns.s2:CAMPAIGN",
    "s3-arena": "rfhoming.campaigns.s3:CAMPAIGN",
    "s4-montecarlo": "rfhoming.campaigns.s4:CAMPAIGN",
}

EPILOG = """\
campaigns (default --runs in brackets):
  s0-table3      S0 Table 3: 5 noise configurations x targets, idealised and realistic [40]
  s0-house       S0 Experiment 2: the four-room house, configuration 5 [80]
  s1-dock        S1 docking trials from random starts [50]
  s2-scenarios   S2: particle filter vs instantaneous error; scenarios A-E, preliminary and full [3 per scenario]
  s3-arena       S3: filters on Table I's noise; trilateration vs multilateration [200 trials per point]
  s4-montecarlo  S4: EKF and UKF on 10,000 simulated beacons, and a filterpy EKF on a subsample [10000]

Each writes OUT/NAME.json (every run and the summary), OUT/NAME.md (the table beside the
paper's, with the command and the radios) and OUT/NAME.png. --radio takes campaigns that run
through the emulator (s0-table3's emulated rows, s0-house, s1-dock, s2-scenarios) to measured
radios; s3-arena and s4-montecarlo, which simulate their papers' RSSI, draw it from the profile's
[rssi.ble] (their receivers are BLE scanners). Seeds are fixed per job, so a campaign gives the
same numbers on 1 worker, on K processes or on a Dask cluster. Finished jobs are kept in
OUT/NAME.partial.jsonl until the campaign completes: run the same command again after a crash
or Ctrl-C and only the unfinished jobs run (delete that file after changing the code).

examples:
  rfhoming campaign s0-table3                    # all cores, results in ./rfhoming-s0-table3-runs40-seed0/
  rfhoming campaign s0-table3 --out docs/results # refresh the committed tables (from the repository)
  rfhoming campaign s1-dock --runs 10 --json     # a quick look, JSON on stdout
  rfhoming campaign s0-house --radio measured    # the house with radios as bad as real ones
  rfhoming campaign s3-arena --radio measured    # S3's lateration on measured BLE RSSI
  rfhoming campaign s4-montecarlo --dask tcp://10.0.0.5:8786
"""


def add_parser(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("campaign", help="reproduce a seed paper's results over many seeded runs",
                       description=__doc__, epilog=EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("name", choices=sorted(REGISTRY), metavar="NAME", help="one of: " + ", ".join(REGISTRY))
    p.add_argument("--runs", type=runs, help="how many runs; what a run is depends on the campaign (see below)")
    p.add_argument("--seed", type=seed, default=0, help="campaign seed; every job derives its own (default 0)")
    p.add_argument("--workers", type=workers, default=min(os.cpu_count() or 1, workers.high),
                   help="local worker processes (default: all cores; 1 runs inline)")
    p.add_argument("--dask", type=dask_address, metavar="ADDRESS", help="run the jobs on the Dask scheduler at ADDRESS instead")
    p.add_argument("--out", type=output_folder, help="output directory (default: ./rfhoming-NAME-runsN-seedS, named for the run; "
                   "docs/results to refresh the repository's committed tables)")
    add_radio_option(p, IDEAL, "ideal, each paper's own set-up")
    p.add_argument("--json", action="store_true", help="print the summary as JSON on stdout")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=command("campaign"))


