"""Silicon Labs' AoA locators read off their MQTT broker as bearing readings (host/bearing.py).

``mqtt+silabs://[USER@]HOST[:PORT][/TOPIC/PREFIX]`` (``mqtts+silabs://``: TLS) names the broker
that the Gecko SDK's ``bt_aoa_host_locator`` publishes to and the root of its topics
(``silabs/aoa`` when the URL has none). A locator's and a tag's id in the topics are
``ble-pd-`` and the device's address: the address (12 hex digits) is the site file's anchor
``id`` and tag id, as for an XPLR-AOA; its azimuth, degrees counter-clockwise from its array's x axis
(docs/protocol.md, "Silicon Labs AoA locator (MQTT)"), becomes the reading's REP 103 azimuth with
that axis as the anchor's boresight. The connection is the site bus's (host/sitebus.py): paho's
thread, reconnects 0.1 s doubling to 5 s, a password from a file or the environment, never the
command line; readings wait in a bounded queue (the oldest dropped and counted) for the owner.
"""

from __future__ import annotations

import collections
import logging
import math
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, replace

import paho.mqtt.client as mqtt

from rfhoming.host.bearing import Bearing
from rfhoming.host.sitebus import Broker, BrokerError, Publisher
from rfhoming.protocol import silabs_aoa
from rfhoming.protocol.credentials import redact

log = logging.getLogger(__name__)

SCHEMES = {"mqtt+silabs": "mqtt", "mqtts+silabs": "mqtts"}
"""Each URL scheme and the broker's own."""

QUEUE_READINGS = 10_000
"""Readings held between the owner's takes at most (at 50 reports/s per locator and tag, 100
pairs for 2 s); the oldest go first, counted in ``dropped``."""


@dataclass(frozen=True)
class Source:
    """A parsed ``mqtt+silabs://`` URL: the broker and the topics' root."""

    broker: Broker
    prefix: str

    @classmethod
    def parse(cls, url: str) -> Source:
        scheme, _, rest = url.partition("://")
        if scheme not in SCHEMES or not rest:
            raise BrokerError(f"{redact(url)!r}: write mqtt+silabs://[USER@]HOST[:PORT][/TOPIC/PREFIX] "
                              "(mqtts+silabs:// for TLS)")
        where, _, path = rest.partition("/")
        prefix = path.strip("/") or silabs_aoa.PREFIX
        try:
            silabs_aoa.check_prefix(prefix)
        except silabs_aoa.SilabsAoaError as exc:
            raise BrokerError(f"{redact(url)!r}: {exc}") from None
        return cls(Broker.parse(f"{SCHEMES[scheme]}://{where}"), prefix)


def to_bearing(t: float, angle: silabs_aoa.Angle) -> Bearing:
    """The neutral reading of a locator's angle: anchor and tag named by their addresses, the
    azimuth wrapped into (-180, 180] degrees (releases write 0..360 or -180..180), radians."""
    az = math.remainder(angle.azimuth_deg, 360.0)
    az = 180.0 if az == -180.0 else az
    el = None if angle.elevation_deg is None else math.radians(angle.elevation_deg)
    return Bearing(t, silabs_aoa.address(angle.locator), silabs_aoa.address(angle.tag), math.radians(az), el, None)


class SilabsLocators:
    """A subscription to every locator's angles under one prefix, as a bounded queue of readings."""

    def __init__(self, source: Source, *, password_file: str | None = None, ca_file: str | None = None,
                 client_id: str = "rfhoming-silabs", queue: int = QUEUE_READINGS,
                 clock: Callable[[], float] = lambda: round(time.time() * 1e6) / 1e6) -> None:
        self.source = replace(source, broker=source.broker.login(password_file))
        self._clock = clock
        self._queue: collections.deque[Bearing] = collections.deque()
        self._cap = queue
        self._lock = threading.Lock()
        self.counters = {"messages": 0, "readings": 0, "bad_payload": 0, "dropped": 0}
        self._warned_bad = False
        self.pub = Publisher(self.source.broker, client_id, ca_file=ca_file)
        self.pub.client.on_message = self._message
        self.pub.on_connect.append(self._subscribe)

    def _subscribe(self) -> None:
        self.pub.client.subscribe(silabs_aoa.subscription(self.source.prefix), qos=0)

    def _message(self, client: mqtt.Client, userdata: object, msg: mqtt.MQTTMessage) -> None:
        t = self._clock()
        self.counters["messages"] += 1
        try:
            angle = silabs_aoa.decode(msg.topic, bytes(msg.payload), self.source.prefix)
        except silabs_aoa.SilabsAoaError as exc:
            self.counters["bad_payload"] += 1
            if not self._warned_bad:  # one line, then counted: a broken publisher must not flood the log
                self._warned_bad = True
                log.warning("refused a locator message (%s); further ones are counted in bad_payload", exc)
            return
        with self._lock:
            if len(self._queue) >= self._cap:
                self._queue.popleft()
                self.counters["dropped"] += 1
            self._queue.append(to_bearing(t, angle))
            self.counters["readings"] += 1

    def take(self) -> list[Bearing]:
        """Every reading that arrived since the last take, oldest first."""
        with self._lock:
            out = list(self._queue)
            self._queue.clear()
        return out

    def check(self) -> None:
        """Raise the broker's refusal for good (a login, a certificate), if it came."""
        if self.pub.failure is not None:
            raise self.pub.failure

    def close(self) -> None:
        self.pub.close()

    def health(self) -> dict[str, object]:
        return {"device": f"{self.source.broker}/{self.source.prefix}", "board": "silabs-aoa", **self.counters,
                "connects": self.pub.counters["connects"], "disconnects": self.pub.counters["disconnects"]}
