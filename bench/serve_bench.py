"""Hostile clients against ``rfhoming serve``: its memory stays bounded and a good client's
stream stays gap-free.

Starts ``rfhoming emulate s0-open --tcp`` and ``rfhoming serve`` on its XPLR-AOA (loopback
only), then for ``--seconds`` runs, all at once:

- ``--churn`` clients (200) that connect, read the hello line and drop, over and over;
- garbage writers (random bytes, 4 KiB every 50 ms), 50 MB-line writers (one line of 50 MB,
  no newline, as fast as the server takes it), slow writers (one byte a second), never-readers
  (a 4 KiB receive buffer, nothing read; reconnecting when cut off); ``--each`` of each kind;
- one well-behaved client that reads every line and checks the item numbers ``n`` follow each
  other without a gap.

It samples the server's RSS (psutil) after a warm-up and at the end, and passes when the growth
is at most ``--max-growth-mb`` (20) and the good client saw no gap and no ``dropped`` notice.
Every loop ends at the deadline; the processes are stopped with SIGINT (then killed).

    python bench/serve_bench.py                    # 60 s, the figures BENCHMARKS.md records
    python bench/serve_bench.py --seconds 10 --json
"""

from __future__ import annotations

import argparse
import asyncio
import json
import random
import signal
import socket
import subprocess
import sys
import time
from typing import Any

import psutil

HOST = "127.0.0.1"


def start(*args: str) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "rfhoming", *args], stdout=subprocess.PIPE,
                            stderr=subprocess.DEVNULL, text=True)


def stop(proc: subprocess.Popen) -> str:
    if proc.poll() is None:
        proc.send_signal(signal.SIGINT)
    try:
        out, _ = proc.communicate(timeout=30)
    except subprocess.TimeoutExpired:
        proc.kill()
        out, _ = proc.communicate()
    return out or ""


class Bench:
    def __init__(self, port: int, deadline: float) -> None:
        self.port, self.deadline = port, deadline
        self.counts: dict[str, int] = {}

    def add(self, key: str, n: int = 1) -> None:
        self.counts[key] = self.counts.get(key, 0) + n

    def left(self) -> float:
        return self.deadline - time.monotonic()

    async def connect(self, rcvbuf: int | None = None,
                      limit: int = 2**16) -> tuple[asyncio.StreamReader, asyncio.StreamWriter]:
        sock = socket.socket()
        if rcvbuf:
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, rcvbuf)
        sock.setblocking(False)
        await asyncio.get_running_loop().sock_connect(sock, (HOST, self.port))
        return await asyncio.open_connection(sock=sock, limit=limit)

    async def churn(self, rng: random.Random) -> None:
        while self.left() > 1:
            try:
                reader, writer = await self.connect()
                await asyncio.wait_for(reader.readline(), 5)
                writer.close()
                self.add("churn_connections")
            except (OSError, TimeoutError):
                self.add("churn_failures")
            await asyncio.sleep(rng.uniform(0.2, 1.5))

    async def writer_loop(self, kind: str, rng: random.Random) -> None:
        """garbage / bigline / slow: write until the server cuts the client off, then again."""
        while self.left() > 1:
            sent = 0
            try:
                reader, writer = await self.connect()
                while self.left() > 1 and not reader.at_eof():
                    if kind == "garbage":
                        data = rng.randbytes(4096)
                    elif kind == "bigline":
                        data = b"x" * 65536 if sent < 50_000_000 else b""
                    else:
                        data = b"y"
                    if data:
                        writer.write(data)
                        sent += len(data)
                        await asyncio.wait_for(writer.drain(), max(0.1, self.left()))
                    await asyncio.sleep({"garbage": 0.05, "bigline": 0, "slow": 1.0}[kind])
                    if kind == "bigline" and not data:
                        await asyncio.sleep(0.5)
                writer.close()
            except (OSError, TimeoutError):
                pass
            self.add(f"{kind}_bytes", sent)
            self.add(f"{kind}_connections")
            await asyncio.sleep(0.2)

    async def never_reader(self, rng: random.Random) -> None:
        """Holds a connection 5-20 s reading nothing (a 4 KiB receive buffer, a 4 KiB stream
        buffer), then aborts it and connects again."""
        while self.left() > 1:
            try:
                _, writer = await self.connect(rcvbuf=4096, limit=4096)
                self.add("never_reader_connections")
                await asyncio.sleep(min(rng.uniform(5, 20), max(0.0, self.left() - 1)))
                writer.transport.abort()
            except OSError:
                pass
            await asyncio.sleep(0.5)

    async def good(self) -> dict[str, Any]:
        reader, writer = await self.connect()
        items, gaps, dropped, last, other = 0, 0, 0, None, 0
        while self.left() > 0:
            try:
                line = await asyncio.wait_for(reader.readline(), max(0.1, self.left()))
            except TimeoutError:
                break
            if not line:
                break
            record = json.loads(line)
            if "n" in record:
                items += 1
                if last is not None and record["n"] != last + 1:
                    gaps += 1
                last = record["n"]
            elif record.get("kind") == "dropped":
                dropped += 1
            else:
                other += 1
        writer.close()
        return {"good_items": items, "good_gaps": gaps, "good_dropped_notices": dropped, "good_other_lines": other}


async def hostile(port: int, seconds: float, churn: int, each: int, seed: int) -> tuple[dict[str, int], dict[str, Any]]:
    bench = Bench(port, time.monotonic() + seconds)
    rng = random.Random(seed)
    tasks = [asyncio.create_task(bench.churn(random.Random(rng.random()))) for _ in range(churn)]
    for kind in ("garbage", "bigline", "slow"):
        tasks += [asyncio.create_task(bench.writer_loop(kind, random.Random(rng.random()))) for _ in range(each)]
    tasks += [asyncio.create_task(bench.never_reader(random.Random(rng.random()))) for _ in range(each)]
    good = await bench.good()
    await asyncio.wait(tasks, timeout=15)
    for task in tasks:
        task.cancel()
    return bench.counts, good


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--seconds", type=float, default=60.0)
    p.add_argument("--churn", type=int, default=200, help="connect/drop clients (default 200)")
    p.add_argument("--each", type=int, default=5, help="garbage, 50 MB-line, slow and never-reading clients each")
    p.add_argument("--max-growth-mb", type=float, default=20.0)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--json", action="store_true")
    args = p.parse_args(argv)

    emulator = start("emulate", "s0-open", "--tcp", "--seed", "3")
    server = None
    try:
        aoa = next(e for e in map(json.loads, iter(emulator.stdout.readline, "")) if e.get("type") == "xplr-aoa")
        server = start("serve", f"ublox-aoa:{aoa['url']}", "--port", "0")
        listening = json.loads(server.stdout.readline())
        port = int(listening["address"].rsplit(":", 1)[1])
        proc = psutil.Process(server.pid)
        time.sleep(3.0)  # the device is set up and streaming
        rss_start = proc.memory_info().rss
        t0 = time.monotonic()
        counts, good = asyncio.run(hostile(port, args.seconds, args.churn, args.each, args.seed))
        rss_end = proc.memory_info().rss
        elapsed = time.monotonic() - t0
        out = stop(server)
    finally:
        for proc_ in (server, emulator):
            if proc_ is not None:
                stop(proc_)
    health = next((json.loads(line) for line in out.splitlines() if '"kind": "server"' in line), {})
    growth = (rss_end - rss_start) / 1e6
    result = {"seconds": round(elapsed, 1), "churn_clients": args.churn, "each": args.each,
              "rss_start_mb": round(rss_start / 1e6, 1), "rss_end_mb": round(rss_end / 1e6, 1),
              "rss_growth_mb": round(growth, 1), **good, **counts,
              "server": {k: health.get(k) for k in ("items", "clients", "dropped", "disconnected_slow",
                                                      "disconnected_input", "refused")}}
    ok = growth <= args.max_growth_mb and good["good_gaps"] == 0 and good["good_dropped_notices"] == 0 \
        and good["good_items"] > 0
    result["pass"] = ok
    if args.json:
        print(json.dumps(result))
    else:
        for key, value in result.items():
            print(f"{key:<28} {value}")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
