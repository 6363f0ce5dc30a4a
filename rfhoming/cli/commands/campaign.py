"""``rfhoming campaign``: run a campaign, write its JSON, Markdown table and plots."""

from __future__ import annotations

import argparse
import importlib
import json
import platform
import shlex
import sys
import time
from pathlib import Path

from rfhoming.campaigns.runner import Campaign, CampaignError, run_jobs
from rfhoming.cli.parsers.campaign import REGISTRY
from rfhoming.host.outputs import Manifest, check_all, replace_text
from rfhoming.protocol.radio_profile import IDEAL, ProfileError, describe

__all__ = ["REGISTRY", "default_folder", "load", "run"]


def default_folder(name: str, runs: int, seed: int, radio: str = IDEAL) -> Path:
    """Under the current directory, named for the run (never docs/results): the same command
    finds its own checkpoint there after a crash."""
    radios = "" if radio == IDEAL else f"-radio-{Path(radio).stem}"
    return Path(f"rfhoming-{name}-runs{runs}-seed{seed}{radios}")


def load(name: str) -> Campaign:
    module, attribute = REGISTRY[name].split(":")
    campaign: Campaign = getattr(importlib.import_module(module), attribute)
    return campaign


def run(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    campaign = load(args.name)
    runs = args.runs if args.runs is not None else campaign.default_runs
    if runs < 1:
        print(f"rfhoming campaign: --runs must be at least 1 ({campaign.runs_help})", file=sys.stderr)
        return 2
    try:
        campaign.check_requirements()
        jobs = campaign.make_jobs(runs, args.seed, args.radio)
        radios = describe(args.radio)
    except (CampaignError, ProfileError) as exc:
        print(f"rfhoming campaign: {exc}", file=sys.stderr)
        return 2
    args.out = args.out or default_folder(args.name, runs, args.seed, args.radio)
    args.out.mkdir(parents=True, exist_ok=True)
    results, table, figure = campaign.outputs(args.out)
    manifest = Manifest(args.out / f"{args.name}.manifest.json", (results, table, figure))
    check_all((results, table, figure, manifest.path))  # a stale NAME.part is named now, not after hours of jobs
    checkpoint = args.out / f"{args.name}.partial.jsonl"  # finished jobs survive a crash or Ctrl-C
    where = f"Dask at {args.dask}" if args.dask else f"{args.workers} worker(s)"
    t0 = time.perf_counter()
    with tqdm(total=len(jobs), desc=f"{args.name} ({where})", unit="job", disable=args.quiet,
              file=sys.stderr, dynamic_ncols=True) as bar:
        try:
            rows = run_jobs(jobs, args.workers, args.dask, bar.update, checkpoint)
        except CampaignError as exc:
            bar.close()
            print(f"rfhoming campaign: {exc}", file=sys.stderr)
            return 2
    wall = time.perf_counter() - t0
    report = campaign.report(rows)
    radio_args = [] if args.radio == IDEAL else ["--radio", args.radio]
    command = "rfhoming campaign " + " ".join(shlex.quote(a) for a in [args.name, "--runs", str(runs), "--seed",
                                                                       str(args.seed), *radio_args])
    meta = {"campaign": args.name, "command": command, "runs": runs, "seed": args.seed, "radio": args.radio,
            "radios": radios, "jobs": len(jobs),
            "wall_s": round(wall, 2), "executor": where, "python": platform.python_version(),
            "machine": platform.machine()}
    manifest.start()  # from here until finish() the folder says its set is not whole
    replace_text(results, json.dumps({**meta, "summary": report.summary, "rows": rows}, indent=1) + "\n")
    replace_text(table, f"# {campaign.description}\n\n`{command}` ({len(jobs)} jobs, {wall:.0f} s on {where}); {radios}\n\n"
                 f"{report.markdown}\n")
    report.plot(figure)
    manifest.finish(campaign=args.name, command=command)
    checkpoint.unlink()
    if args.json:
        print(json.dumps({**meta, "summary": report.summary}, indent=1))
    else:
        print(radios + "\n")
        print(report.markdown)
        print(f"\n{len(jobs)} jobs in {wall:.1f} s; wrote {results}, {table.name}, {figure.name}")
    return 0
