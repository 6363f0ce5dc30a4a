"""Run a campaign's jobs on an executor and keep their results in job order.

A job is plain data (a function path and its keyword arguments), so the same campaign runs
inline, on local processes (``concurrent.futures.ProcessPoolExecutor``) or on a Dask cluster
(``distributed.Client(address).get_executor()``, the same Executor interface). Every job
carries its own seed derived from the campaign seed and its index, so results do not depend on
the number of workers or on where a job ran.
"""

from __future__ import annotations

import concurrent.futures as cf
import importlib
import logging
import os
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Job:
    index: int
    fn: str  # "package.module:function"
    kwargs: dict[str, Any] = field(default_factory=dict)


def execute(job: Job) -> dict[str, Any]:
    """Run one job (in whichever process or worker it landed)."""
    module, name = job.fn.split(":")
    result = getattr(importlib.import_module(module), name)(**job.kwargs)
    return {"index": job.index, **result}


@dataclass
class Report:
    summary: dict[str, Any]  # machine-readable figures
    markdown: str  # the side-by-side tables
    plots: dict[str, Callable[[Path], None]] = field(default_factory=dict)  # file name -> writer


@dataclass(frozen=True)
class Campaign:
    name: str
    description: str
    runs_help: str  # what --runs counts for this campaign
    default_runs: int
    jobs: Callable[[int, int], list[Job]]  # (runs, seed) -> jobs
    report: Callable[[list[dict[str, Any]]], Report]


class CampaignError(RuntimeError):
    """A campaign that cannot run here; the message says what to do."""


@contextmanager
def executor(workers: int, dask_address: str | None) -> Iterator[cf.Executor | None]:
    """None means inline (one worker, no pool: simplest to debug and to profile)."""
    if dask_address is not None:
        try:
            from distributed import Client
        except ImportError:
            raise CampaignError("--dask needs the distributed package: pip install 'rfhoming[campaign]'") from None
        try:
            client = Client(dask_address, timeout="10s")
        except OSError as exc:
            raise CampaignError(f"no Dask scheduler at {dask_address} ({exc}); start one with "
                                f"`dask scheduler` and `dask worker ADDRESS`, or drop --dask") from None
        try:
            yield client.get_executor()
        finally:
            client.close()
        return
    if workers <= 1:
        yield None
        return
    with cf.ProcessPoolExecutor(max_workers=workers) as pool:
        yield pool


def run_jobs(jobs: list[Job], workers: int = os.cpu_count() or 1, dask_address: str | None = None,
             progress: Callable[[int], None] = lambda n: None) -> list[dict[str, Any]]:
    """Every job's result, in job order; ``progress(1)`` after each one finishes."""
    results: dict[int, dict[str, Any]] = {}
    with executor(workers, dask_address) as pool:
        if pool is None:
            for job in jobs:
                results[job.index] = execute(job)
                progress(1)
        else:
            futures = [pool.submit(execute, job) for job in jobs]
            try:
                for future in cf.as_completed(futures):
                    result = future.result()
                    results[result["index"]] = result
                    progress(1)
            except BaseException:
                for f in futures:
                    f.cancel()
                raise
    return [results[job.index] for job in jobs]
