"""Run a campaign's jobs on an executor and keep their results in job order.

A job is plain data (a function path and its keyword arguments), so the same campaign runs
inline, on local processes (``concurrent.futures.ProcessPoolExecutor``) or on a Dask cluster
(``distributed.Client(address).get_executor()``, the same Executor interface). Every job
carries its own seed derived from the campaign seed and its index, so results do not depend on
the number of workers or on where a job ran.

A checkpoint file (JSON lines, one finished job each) keeps finished jobs when a campaign is
stopped or crashes; the next run with the same jobs reads it and runs only the rest.
"""

from __future__ import annotations

import concurrent.futures as cf
import importlib
import importlib.util
import json
import multiprocessing
import logging
import os
import signal
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

from rfhoming.protocol.errors import Error
from rfhoming.protocol.radio_profile import IDEAL

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
    plot: Callable[[Path], None]  # draws the figure to the file it is given (the campaign's NAME.png)


@dataclass(frozen=True)
class Campaign:
    name: str
    description: str
    runs_help: str  # what --runs counts for this campaign
    default_runs: int
    jobs: Callable[[int, int], list[Job]]  # (runs, seed) -> jobs
    report: Callable[[list[dict[str, Any]]], Report]
    requires: tuple[str, ...] = ()  # optional packages its jobs import

    def make_jobs(self, runs: int, seed: int, radio: str = IDEAL) -> list[Job]:
        """The jobs, each told the radios (``--radio``) when they are not the idealised ones: every
        campaign's jobs take ``radio=`` (they run through the emulator's radios, or draw their
        simulated RSSI from a profile's [rssi.NAME]: s3-arena, s4-montecarlo, campaigns/rssi_draws.py)."""
        if radio == IDEAL:
            return self.jobs(runs, seed)
        return [replace(job, kwargs={**job.kwargs, "radio": radio}) for job in self.jobs(runs, seed)]

    def outputs(self, folder: Path) -> tuple[Path, Path, Path]:
        """What ``rfhoming campaign`` writes in ``folder``: NAME.json (every run and the summary),
        NAME.md (the table beside the paper's) and NAME.png (the report's figure)."""
        return folder / f"{self.name}.json", folder / f"{self.name}.md", folder / f"{self.name}.png"

    def check_requirements(self) -> None:
        """Fail before the first job, not after hours of them, when a package is missing."""
        missing = [m for m in self.requires if importlib.util.find_spec(m) is None]
        if missing:
            raise CampaignError(f"{self.name} needs {', '.join(missing)}: pip install 'rfhoming[campaign]'")


class CampaignError(Error, RuntimeError):
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
    with cf.ProcessPoolExecutor(max_workers=workers, initializer=_terminated_by_sigterm) as pool:
        yield pool


def _terminated_by_sigterm() -> None:
    """A worker ends at SIGTERM (terminate()), whatever handler it inherited from its parent."""
    signal.signal(signal.SIGTERM, signal.SIG_DFL)


def _key(job: Job) -> str:
    return json.dumps([job.index, job.fn, job.kwargs], sort_keys=True, default=str)


def load_checkpoint(path: Path, jobs: list[Job]) -> dict[int, dict[str, Any]]:
    """Results of ``jobs`` already in the checkpoint (same index, function and arguments)."""
    if not path.is_file():
        return {}
    wanted = {_key(j): j.index for j in jobs}
    done = {}
    for line in path.read_text().splitlines():
        try:
            entry = json.loads(line)
        except json.JSONDecodeError:  # a line cut short by the crash
            continue
        index = wanted.get(entry.get("key"))
        if index is not None:
            done[index] = entry["result"]
    return done


def run_jobs(jobs: list[Job], workers: int = os.cpu_count() or 1, dask_address: str | None = None,
             progress: Callable[[int], object] = lambda n: None, checkpoint: Path | None = None) -> list[dict[str, Any]]:
    """Every job's result, in job order; ``progress(1)`` after each one finishes. With a
    ``checkpoint`` file, jobs already in it are not run again and each new result is appended."""
    results: dict[int, dict[str, Any]] = load_checkpoint(checkpoint, jobs) if checkpoint else {}
    progress(len(results))
    todo = [job for job in jobs if job.index not in results]
    keys = {job.index: _key(job) for job in todo}
    sink = checkpoint.open("a") if checkpoint else None

    def finished(result: dict[str, Any]) -> None:
        results[result["index"]] = result
        if sink is not None:
            sink.write(json.dumps({"key": keys[result["index"]], "result": result}) + "\n")
            sink.flush()
        progress(1)

    try:
        _run(todo, workers, dask_address, finished)
    finally:
        if sink is not None:
            sink.close()
    return [results[job.index] for job in jobs]


def _run(jobs: list[Job], workers: int, dask_address: str | None, finished: Callable[[dict[str, Any]], None]) -> None:
    with executor(workers, dask_address) as pool:
        if pool is None:
            for job in jobs:
                finished(execute(job))
        else:
            futures = [pool.submit(execute, job) for job in jobs]
            try:
                for future in cf.as_completed(futures):
                    finished(future.result())
            except BaseException:
                if isinstance(pool, cf.ProcessPoolExecutor):  # Ctrl-C, SIGTERM: the running jobs end too
                    for child in multiprocessing.active_children():
                        child.terminate()  # the pool then fails its futures (cancelling them first made
                    # Python 3.11's pool manager raise InvalidStateError, a traceback, when workers died)
                else:
                    for f in futures:
                        f.cancel()
                raise
