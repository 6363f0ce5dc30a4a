"""How long a client of ``rfhoming serve`` hears nothing when a device is unplugged.

An emulated s0-open world (XPLR-AOA and base on ptys) runs in a thread of this process, so the
bench unplugs the XPLR-AOA's link itself -- the emulator's own unplug -- exactly when it wants;
``rfhoming serve`` (a subprocess) owns both devices and one client reads every line it sends.
``--unplugs`` times (5) the bench waits for the AoA's angles, unplugs it, waits ``--hold``
seconds (2) and plugs it back, and measures, from the unplug:

- ``silence_s``: until the client's next line about the AoA that is not an angle (an angle may
  still be in flight): protocol 1's ``disconnected`` notice; before protocol 1, whatever came
  first once it was back -- its set-up chatter;
- ``disconnected_s``: until the ``disconnected`` notice (none before protocol 1);
- ``back_s``: from the replug until the next angle.

Runs against any version of the server (it reads LF or CR LF lines).

    python bench/serve_unplug_bench.py --json
"""

from __future__ import annotations

import argparse
import json
import signal
import socket
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

SAFETY_S = 60.0  # a hang guard on each wait


class Reader:
    """Every line the server sends, with the monotonic time it arrived, in a thread."""

    def __init__(self, port: int) -> None:
        self.sock = socket.create_connection(("127.0.0.1", port), timeout=SAFETY_S)
        self.lines: list[tuple[float, dict]] = []
        self.cond = threading.Condition()
        threading.Thread(target=self._run, daemon=True).start()

    def _run(self) -> None:
        buffer = b""
        while data := self._recv():
            *lines, buffer = (buffer + data).split(b"\n")
            now = time.monotonic()
            with self.cond:
                self.lines += [(now, json.loads(line)) for line in lines if line.strip()]
                self.cond.notify_all()

    def _recv(self) -> bytes:
        try:
            return self.sock.recv(65536)
        except OSError:
            return b""

    def first(self, since: float, test) -> float:
        """The arrival time of the first line after ``since`` that passes ``test``."""
        deadline = time.monotonic() + SAFETY_S
        with self.cond:
            while True:
                for t, record in self.lines:
                    if t >= since and test(record):
                        return t
                left = deadline - time.monotonic()
                if left <= 0:
                    raise TimeoutError("no such line")
                self.cond.wait(left)


def news_of_aoa(record: dict) -> bool:
    return record.get("device") == "aoa" and record.get("kind") != "angle"


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--unplugs", type=int, default=5)
    p.add_argument("--hold", type=float, default=2.0, help="seconds each unplug lasts (default 2)")
    p.add_argument("--json", action="store_true")
    args = p.parse_args(argv)

    from rfhoming.emulator.runtime import Emulator
    from rfhoming.emulator.scenario import load
    from rfhoming.emulator.threaded import EmulatorThread

    world = EmulatorThread(Emulator(load("s0-open", seed=3, target=(3.0, 2.0)), transport="pty", seed=3, speed=1.0,
                                    link_dir=Path(tempfile.mkdtemp())), SAFETY_S)
    server = subprocess.Popen([sys.executable, "-m", "rfhoming", "serve",
                               f"xplr-aoa:{world.endpoints['aoa']['path']},name=aoa",
                               f"base:{world.endpoints['base']['path']},name=base", "--port", "0"],
                              stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    runs = []
    try:
        port = int(json.loads(server.stdout.readline())["address"].rsplit(":", 1)[1])
        reader = Reader(port)
        link = world.emulator.device("aoa").link
        for _ in range(args.unplugs):
            reader.first(time.monotonic(), lambda r: r.get("kind") == "angle")
            unplugged = time.monotonic()
            world.call(link.unplug())
            time.sleep(args.hold)
            replugged = time.monotonic()
            world.call(link.replug())
            back = reader.first(replugged, lambda r: r.get("kind") == "angle")
            silence = reader.first(unplugged, news_of_aoa)
            notices = [t for t, r in reader.lines if t >= unplugged and r.get("state") == "disconnected"]
            runs.append({"silence_s": round(silence - unplugged, 3), "back_s": round(back - replugged, 3),
                         "disconnected_s": round(notices[0] - unplugged, 3) if notices else None})
    finally:
        server.send_signal(signal.SIGINT)
        try:
            server.wait(timeout=30)
        except subprocess.TimeoutExpired:
            server.kill()
        world.close()
    notices = [r["disconnected_s"] for r in runs if r["disconnected_s"] is not None]
    result = {"unplugs": args.unplugs, "hold_s": args.hold,
              "silence_s_median": statistics.median(r["silence_s"] for r in runs),
              "silence_s_max": max(r["silence_s"] for r in runs),
              "disconnected_notices": len(notices),
              "disconnected_s_max": max(notices) if notices else None,
              "back_s_median": statistics.median(r["back_s"] for r in runs), "runs": runs}
    print(json.dumps(result) if args.json else "\n".join(f"{k}: {v}" for k, v in result.items()))
    return 0


if __name__ == "__main__":
    sys.exit(main())
