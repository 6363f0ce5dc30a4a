"""``demo --foxglove`` as a person watches it, checked by a client written from the published
Foxglove WebSocket spec (foxglove/ws-protocol docs/spec.md) with ``websockets``: which
subprotocols the view takes, the ``time`` capability and robot-time messages, JSON schemas,
REP 105 transforms, scene lifetimes; a viewer that connects 3 s after the address is printed
still sees the whole run (the demo waits for it); the run is paced at robot time."""

from __future__ import annotations

import json
import subprocess
import sys
import time
from pathlib import Path

import pytest
import rigs
from websockets.exceptions import InvalidStatus
from websockets.sync.client import connect

from rfhoming.host.foxglove_view import FoxgloveView
from test_foxglove_view import SAFETY_S, watch


def start_demo(out: Path, *args: str) -> tuple[subprocess.Popen, str]:
    demo = subprocess.Popen([sys.executable, "-m", "rfhoming", "demo", "--out", str(out), "--foxglove=0", "--json",
                             "--linger", "0", *args], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    first = json.loads(rigs.readline(demo, "stderr", SAFETY_S))
    assert first == {"kind": "listening", "address": first["address"],
                     "protocols": ["foxglove.websocket.v1", "foxglove.sdk.v1"]}
    return demo, first["address"]


def finish(demo: subprocess.Popen) -> dict:
    out, err = demo.communicate(timeout=SAFETY_S * 3)
    assert demo.returncode == 0, err
    return json.loads(out)


def test_the_view_takes_both_names_of_the_protocol_and_answers_with_the_offered_one() -> None:
    """foxglove-sdk's server alone takes only foxglove.sdk.v1; the view's front takes the spec's
    foxglove.websocket.v1 too (Foxglove's FoxgloveClient, Lichtblick 1.21 and older) and answers
    with it; a client offering neither still gets HTTP 400."""
    view = FoxgloveView(port=0)
    try:
        with pytest.raises(InvalidStatus) as refused:
            connect(view.address, subprotocols=["ros1"], open_timeout=SAFETY_S)
        assert refused.value.response.status_code == 400
        for offered, answer in ((["foxglove.sdk.v1"], "foxglove.sdk.v1"),
                                (["foxglove.websocket.v1"], "foxglove.websocket.v1"),
                                (["foxglove.websocket.v1", "foxglove.sdk.v1"], "foxglove.sdk.v1")):
            with connect(view.address, subprotocols=offered, open_timeout=SAFETY_S) as ws:
                assert ws.subprotocol == answer
                info = json.loads(ws.recv(timeout=SAFETY_S))
                assert info["op"] == "serverInfo" and "time" in info["capabilities"]
    finally:
        view.close()


@pytest.mark.slow
def test_a_viewer_3_s_late_sees_the_whole_run_at_robot_time(tmp_path: Path) -> None:
    demo, address = start_demo(tmp_path, "--speed", "4")
    time.sleep(3)  # a person opening Foxglove; the demo waits for the first subscription
    info: dict = {}
    got = watch(address, info=info)
    summary = finish(demo)
    runlog = [json.loads(line) for line in (tmp_path / "run.jsonl").read_text().splitlines()]

    # the whole run: every command of the run log, from the first
    assert got["/rfhoming/command"] == [r for r in runlog if r["kind"] == "command"]
    # the server's clock is the robot's: time messages from 0 to the run's end, never going back
    ticks = [t / 1e9 for t in info["time"]]
    assert "time" in info["serverInfo"]["capabilities"]
    assert ticks == sorted(ticks) and 0 <= ticks[0] < 1 and abs(ticks[-1] - summary["simulated_time_s"]) < 1
    # REP 105: the sensor frames hang on base_link, base_link on odom
    static = {(tf.parent_frame_id, tf.child_frame_id) for m in got["/tf_static"] for tf in m.transforms}
    assert {("base_link", f) for f in ("aoa_link", "laser", "rss_link", "ble_link")} <= static
    assert {(tf.parent_frame_id, tf.child_frame_id) for m in got["/tf"] for tf in m.transforms} == {("odom", "base_link")}
    # scene entities expire; JSON channels carry their schema's required fields
    entities = [e for u in got["/rfhoming/scene"] for e in u.entities]
    assert entities and all(e.lifetime.seconds + e.lifetime.nanos > 0 for e in entities)
    schemas = {c["topic"]: json.loads(c["schema"]) for c in info["channels"] if c["encoding"] == "json"}
    for topic, schema in schemas.items():
        for message in got.get(topic, []):
            assert set(schema["required"]) <= set(message), topic


@pytest.mark.slow
def test_demo_with_foxglove_runs_at_robot_time(tmp_path: Path) -> None:
    """At --speed 4 a run of T simulated seconds takes at least T/4 wall seconds (a lower
    bound: a slow machine only makes it longer)."""
    demo, address = start_demo(tmp_path, "--speed", "4")
    with connect(address, subprotocols=["foxglove.sdk.v1"], open_timeout=SAFETY_S) as ws:
        channels = []
        while not channels:
            op = json.loads(ws.recv(timeout=SAFETY_S))
            channels = op.get("channels", []) if op["op"] == "advertise" else []
        ws.send(json.dumps({"op": "subscribe", "subscriptions": [{"id": 1, "channelId": channels[0]["id"]}]}))
        started = time.monotonic()
        summary = finish(demo)
        assert time.monotonic() - started >= summary["simulated_time_s"] / 4 * 0.9
