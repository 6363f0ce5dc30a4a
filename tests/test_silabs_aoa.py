"""Silicon Labs' AoA locator over MQTT: the codec (protocol/silabs_aoa.py), the reading it becomes
(host/silabs_source.py), the emulated locator (emulator/silabs_locator.py) and, on a local
Mosquitto, ``rfhoming locate --from mqtt+silabs://`` fixing a tag the emulated locators see."""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
import threading
from pathlib import Path

import pytest

import rigs
from brokers import MOSQUITTO, free_port, start, stop
from rfhoming.emulator.silabs_locator import SilabsLocator
from rfhoming.protocol import silabs_aoa as sa

ENV = {**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[1] / "src")}
LOC, TAG = "ble-pd-842E1431C8B1", "ble-pd-588E81A54222"

SDK_PAYLOAD = (b'{\n\t"azimuth":\t-35.5,\n\t"azimuth_stdev":\t1.25,\n\t"elevation":\t12.75,\n\t'
               b'"elevation_stdev":\t2,\n\t"distance":\t1.5,\n\t"distance_stdev":\t0,\n\t"sequence":\t4711\n}')
"""What cJSON_Print writes for aoa_serialize_angle (tabs, one key a line)."""


def test_topic_and_the_sdks_payload_decode() -> None:
    topic = f"silabs/aoa/angle/{LOC}/{TAG}"
    assert sa.parse_topic(topic) == (LOC, TAG)
    a = sa.decode(topic, SDK_PAYLOAD)
    assert (a.locator, a.tag, a.azimuth_deg, a.elevation_deg, a.distance_m, a.sequence) == \
        (LOC, TAG, -35.5, 12.75, 1.5, 4711)
    assert a.azimuth_stdev_deg == 1.25 and a.quality is None
    old = sa.decode(topic, b'{"azimuth": 10, "elevation": 0, "distance": 2, "quality": 0, "sequence": 3}')
    assert old.quality == 0  # an older release's payload: quality, no stdevs
    nlos = sa.decode(topic, b'{"azimuth": 10, "azimuth_stdev": -4.5}')
    assert nlos.azimuth_stdev_deg == -4.5  # the library's sign for "likely non-line-of-sight"


def test_encode_decodes_to_itself() -> None:
    a = sa.Angle(LOC, TAG, 271.5, -3.0, 2.5, 9, 1.0, 1.5)
    back = sa.decode(sa.angle_topic(LOC, TAG, "site/hall"), sa.encode(a), "site/hall")
    assert back == a


@pytest.mark.parametrize(("topic", "payload", "says"), [
    ("silabs/aoa/angle/a", b'{"azimuth": 1}', "expected silabs/aoa/angle/LOCATOR/TAG"),
    ("silabs/aoa/position/a/b", b'{"azimuth": 1}', "expected"),
    ("silabs/aoa/angle/a/b/c", b'{"azimuth": 1}', "expected"),
    ("silabs/aoa/angle/a/b", b'{"azimuth": NaN}', "NaN"),
    ("silabs/aoa/angle/a/b", b'{"azimuth": Infinity}', "Infinity"),
    ("silabs/aoa/angle/a/b", b'{"azimuth": 1e999}', "not a number"),
    ("silabs/aoa/angle/a/b", b'{"azimuth": 400}', "not a number in -360..360"),
    ("silabs/aoa/angle/a/b", b'{"azimuth": 1, "elevation": 91}', "elevation"),
    ("silabs/aoa/angle/a/b", b'{"azimuth": true}', "not a number"),
    ("silabs/aoa/angle/a/b", b'{"azimuth": "12"}', "not a number"),
    ("silabs/aoa/angle/a/b", b'{"elevation": 1}', "no azimuth"),
    ("silabs/aoa/angle/a/b", b'[1, 2]', "flat JSON object"),
    ("silabs/aoa/angle/a/b", b'{"azimuth": 1, "x": {"y": 2}}', "flat JSON object"),
    ("silabs/aoa/angle/a/b", b'[' * 2000 + b']' * 2000, "not JSON|flat JSON object"),
    ("silabs/aoa/angle/a/b", b'{"azimuth": 1, "pad": "' + b'x' * 5000 + b'"}', "bytes"),
    ("silabs/aoa/angle/a/b", b'\xff\xfe', "not JSON"),
    ("silabs/aoa/angle/a/b", b'{"azimuth": 1', "not JSON"),
])
def test_bad_messages_are_refused_in_one_line(topic: str, payload: bytes, says: str) -> None:
    with pytest.raises(sa.SilabsAoaError, match=says) as err:
        sa.decode(topic, payload)
    assert "\n" not in str(err.value) and len(str(err.value)) < 300


def test_prefix_and_ids_are_checked() -> None:
    for bad in ("", "a/+/b", "a//b", "#", "a b"):
        with pytest.raises(sa.SilabsAoaError, match="topic prefix"):
            sa.check_prefix(bad)
    with pytest.raises(sa.SilabsAoaError, match="locator id"):
        sa.angle_topic("a/b", TAG)


def test_azimuth_becomes_rep103_radians_over_the_circle() -> None:
    pytest.importorskip("paho.mqtt")
    from rfhoming.host.silabs_source import to_bearing

    def az(deg: float) -> float:
        return to_bearing(0.0, sa.Angle(LOC, TAG, deg, 5.0)).azimuth_deg

    assert [az(d) for d in (0.0, 30.0, 270.0, 180.0, -180.0, 359.0, -90.0)] == \
        [0.0, 30.0, -90.0, 180.0, 180.0, -1.0, -90.0]
    r = to_bearing(12.5, sa.Angle(LOC, TAG, 30.0, 5.0))
    assert (r.t, r.anchor, r.tag, r.elevation_deg, r.rssi) == (12.5, "842E1431C8B1", "588E81A54222", 5.0, None)
    assert to_bearing(0.0, sa.Angle("hall-3", "cart", 1.0)).anchor == "hall-3"  # not the SDK's form: as it is
    assert to_bearing(0.0, sa.Angle("BLE-sr-842e1431c8b1", TAG, 1.0)).anchor == "842E1431C8B1"
    assert r.clockwise_deg == -30.0  # a tag to the left: negative in the XPLR-AOA's sign


def test_url_parse_prefix_and_errors() -> None:
    pytest.importorskip("paho.mqtt")
    from rfhoming.host.silabs_source import Source
    from rfhoming.host.sitebus import BrokerError

    s = Source.parse("mqtt+silabs://loc@broker.local")
    assert (s.broker.host, s.broker.port, s.broker.tls, s.broker.username, s.prefix) == \
        ("broker.local", 1883, False, "loc", "silabs/aoa")
    t = Source.parse("mqtts+silabs://broker.local:9000/hall/east/")
    assert (t.broker.port, t.broker.tls, t.prefix) == (9000, True, "hall/east")
    for bad in ("mqtt+silabs://", "mqtt+silabs://h/a/+", "mqtt+silabs://h:0"):
        with pytest.raises(BrokerError):
            Source.parse(bad)
    with pytest.raises(BrokerError) as err:
        Source.parse("mqtt+silabs://u:hunter2@h/+")
    assert "hunter2" not in str(err.value)


def test_emulated_locator_angles_follow_rep103() -> None:
    loc = SilabsLocator(LOC, (0.0, 0.0, 1.0), yaw_deg=90.0, sigma_deg=0.0, bias_sigma_deg=0.0)
    az, el = loc.true_angles((-1.0, 1.0, 1.0))  # boresight +y; the tag ahead and to its left
    assert az == pytest.approx(45.0) and el == pytest.approx(0.0)
    a = loc.angle(TAG, (1.0, 1.0, 1.0))  # ahead and to its right: 315 as the SDK writes 0..360
    assert a.azimuth_deg == pytest.approx(315.0) and a.sequence == 1
    behind = loc.angle(TAG, (0.0, -2.0, 1.0))
    assert behind.azimuth_deg == pytest.approx(180.0)


# -- against a real broker -----------------------------------------------------------------------
SITE = """\
[site]
name = "silabs-room"
rate_hz = 5
sigma_deg = 3.0
az_compression = 0.0

[anchors.west]
id = "000000000A01"
angle_model = "spherical"
position = [0.0, 5.0, 2.0]
yaw_deg = 0.0

[anchors.south]
id = "000000000A02"
angle_model = "spherical"
position = [5.0, 0.0, 2.0]
yaw_deg = 90.0

[anchors.east]
id = "000000000A03"
angle_model = "spherical"
position = [10.0, 5.0, 2.0]
yaw_deg = 180.0

[tags.588E81A54222]
name = "cart"
height = 1.0
"""


@pytest.mark.skipif(MOSQUITTO is None, reason="mosquitto not installed (.ci/run installs it)")
def test_locate_fixes_a_tag_the_emulated_locators_publish(tmp_path: Path) -> None:
    pytest.importorskip("paho.mqtt")
    from rfhoming.host.sitebus import Broker, Publisher

    port = free_port()
    broker = start(tmp_path, port)
    site = tmp_path / "site.toml"
    site.write_text(SITE)
    truth = (6.0, 3.0, 1.0)
    locators = [SilabsLocator(f"ble-pd-000000000A0{i + 1}", pos, yaw_deg=yaw, prefix="hall/aoa", sigma_deg=1.0,
                              bias_sigma_deg=0.5)
                for i, (pos, yaw) in enumerate((((0.0, 5.0, 2.0), 0.0), ((5.0, 0.0, 2.0), 90.0),
                                                ((10.0, 5.0, 2.0), 180.0)))]
    done = threading.Event()
    pub = Publisher(Broker("127.0.0.1", port, False, None), "emulated-silabs-locators")

    def publish() -> None:  # 10 reports a second per locator, as the RTL library's fast modes give
        while not done.wait(0.1):
            for loc in locators:
                for topic, payload in loc.messages({TAG: truth}):
                    pub.publish(topic, payload)
            pub.publish("hall/aoa/angle/ble-pd-000000000A01/x", b'{"azimuth": NaN}')  # refused, counted

    feeder = threading.Thread(target=publish, daemon=True)
    feeder.start()
    proc = subprocess.Popen([sys.executable, "-m", "rfhoming.cli.main", "locate", str(site), "--from",
                             f"mqtt+silabs://127.0.0.1:{port}/hall/aoa", "--no-track", "--duration", "600"],
                            env=ENV, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    positions: list[dict[str, object]] = []
    try:
        assert proc.stdout is not None
        while len(positions) < 10:  # each line waited for with a deadline (a hang guard, not a speed target)
            line = rigs.readline(proc, deadline_s=300)
            if not line:
                proc.wait(timeout=60)
                pytest.fail(f"locate ended early: {rigs.readline(proc, 'stderr', 60)}")
            record = json.loads(line)
            if record.get("kind") == "position":
                positions.append(record)
    finally:
        proc.terminate()
        _, err = proc.communicate(timeout=60)
        done.set()
        feeder.join(10)
        pub.close()
        stop(broker)
    assert len(positions) >= 10, err
    for p in positions:
        assert p["tag"] == "588E81A54222"
        miss = math.dist((float(p["x"]), float(p["y"])), truth[:2])  # type: ignore[arg-type]
        assert miss < 0.5, p
    counters = [json.loads(line) for line in err.splitlines() if line.startswith('{"kind": "counters"')]
    assert counters and counters[0]["board"] == "silabs-aoa", err
    assert counters[0]["bad_payload"] >= 1 and counters[0]["readings"] >= 30  # the NaN refused, not fed
