"""The live view under hostile WebSocket clients: none can stop the server, the run or Ctrl-C.

The cause of the hang: foxglove-sdk's ``stop()`` waits, forever, for a client that reads nothing
(it cannot flush to it), and the view called it on the main thread after the run -- so Ctrl-C
during ``--linger`` did nothing. The view's front (host/foxglove_front.py) now stands between the
SDK and every client and closes them all before the SDK stops."""

from __future__ import annotations

import json
import random
import subprocess
import sys
import threading
from pathlib import Path

import pytest
from websockets.sync.client import connect

from rfhoming.host.foxglove_view import FoxgloveView

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "bench"))
from foxglove_hostile_bench import frame, handshake, junk  # noqa: E402

SAFETY_S = 60


def test_clients_that_never_read_do_not_hold_up_close_or_others() -> None:
    view = FoxgloveView(port=0)
    port = int(view.address.rsplit(":", 1)[1])
    closed = threading.Event()
    never = []
    try:
        subscribe = json.dumps({"op": "subscribe", "subscriptions": [{"id": i, "channelId": i} for i in range(1, 20)]})
        for _ in range(3):
            never.append(handshake(port, rcvbuf=4096, protocol="foxglove.sdk.v1"))  # the name both views take
            never[-1].recv(1)  # the handshake's answer has begun: a subscription before it counts for nothing
            never[-1].sendall(frame(subscribe.encode(), 1))
        with handshake(port, protocol="foxglove.sdk.v1") as garbage:
            rng = random.Random(0)
            try:
                for _ in range(50):
                    garbage.sendall(junk(rng))
            except (BrokenPipeError, ConnectionResetError):
                pass  # the view cut the garbage off (how soon depends on the machine's load): what it should do
        for i in range(20_000):  # far more than the never-readers' buffers hold
            view._on_pose(i * 1e-3, 0.0, 0.0)
            view.on_runlog({"kind": "command", "t": i * 1e-3, "v": 0.1, "w": 0.0})
        with connect(view.address, subprotocols=["foxglove.sdk.v1"], open_timeout=SAFETY_S) as ws:
            assert json.loads(ws.recv(timeout=SAFETY_S))["op"] == "serverInfo"
    finally:
        closer = threading.Thread(target=lambda: (view.close(), closed.set()), daemon=True)
        closer.start()
        closer.join(SAFETY_S)
        for sock in never:
            sock.close()
    assert closed.is_set(), "close() waited on clients that never read"


@pytest.mark.slow
def test_a_demo_under_the_hostile_mix_runs_serves_and_ends_on_ctrl_c() -> None:
    """One run of bench/foxglove_hostile_bench.py (docs/testing.md has 20): connect/drop,
    silent, garbage, 17 MiB frames and never-readers beside a good client."""
    done = subprocess.run([sys.executable, str(ROOT / "bench" / "foxglove_hostile_bench.py"), "--runs", "1", "--json"],
                          capture_output=True, text=True, timeout=300)
    report = json.loads(done.stdout)
    run = report["per_run"][0]
    assert report["hangs"] == 0 and done.returncode == 0, run
    assert run["run_finished"] and run["good_after_mix"] > 0 and run["late_handshake"] and run["exit_s"] is not None
