"""The site bus over MQTT (paho-mqtt 2.x, MQTT 3.1.1): gateways publish angle batches, workers locate.

Topics and payloads are protocol/sitebus.py's (docs/protocol.md, "Site bus (MQTT)"). QoS 0 on
both: an angle is worth something for one window (0.3 s) and a position until the next tick, so a
redelivery after a reconnect is useless and QoS 1's PUBACK per message costs broker and link time;
a loss is still seen, from the per-partition ``seq`` gaps the worker counts.

:class:`Publisher` is the one connection a process keeps: paho's network thread reconnects (0.1 s
doubling to 5 s), messages published while the broker is away, or while paho already holds a
buffer's worth unsent for a slow one, wait in a bounded buffer (the oldest dropped and counted when
full) and go out in order once there is room.
"""

from __future__ import annotations

import collections
import itertools
import logging
import math
import os
import select
import ssl
import sys
import threading
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, replace
from urllib.parse import unquote, urlsplit

import numpy as np
import paho.mqtt.client as mqtt
from paho.mqtt.enums import CallbackAPIVersion
from paho.mqtt.reasoncodes import ReasonCode

from rfhoming.host.bearing import Bearing
from rfhoming.host.estimation.batch import INCONSISTENT_CHI2_PER_DOF, BatchLocator
from rfhoming.host.site import Site
from rfhoming.protocol import sitebus
from rfhoming.protocol.errors import Error
from rfhoming.protocol.credentials import PASSWORD_ENV, redact

log = logging.getLogger(__name__)

BUFFER_MESSAGES = 10_000
"""Messages held while the broker is away (at 20 ms batches x 8 partitions: 1.25 s of a gateway)."""

INBOX_MESSAGES = 100_000
"""Batches a worker holds between its ticks at most (the oldest are dropped and counted)."""

OFFSET_SAMPLES = 200
"""Batches per gateway over which the worker takes the minimum delay (its clock-offset estimate)."""

MAX_GATEWAYS = 4096
"""Gateways a worker keeps a clock offset and sequence numbers of; past it the one heard from
least lately is forgotten (counted): a gateway name is whatever a message says, and a stream of
new ones (garbage, or a gateway renamed at each start) must not grow the worker without end."""


MAX_WORKERS = 1024
"""Other workers' claims a worker keeps at most: a claim's name is whatever its topic says, and a
flood of new ones must not grow the worker (or the partition hashing) without end (counted,
``claims_ignored``)."""


READ_BURST = 1000
"""Packets :meth:`Publisher.service` reads at most per call (paho's own loop reads one)."""

RECONNECT_MIN_S, RECONNECT_MAX_S = 0.1, 5.0
"""Seconds between tries to reach a lost broker: the first, doubling up to the last."""

CONNECT_TIMEOUT_S = 1.0
"""Seconds one try to reach the broker may block (TCP connect, TLS handshake; paho's default is 5):
a worker tries in its own loop, and --duration, Ctrl-C and SIGTERM must end it promptly."""

MISMATCH_TRIES = 3
"""Tries in a row whose connection the broker took and then closed before any MQTT answer (TLS
against a plaintext port, plaintext against a TLS port) before that is taken for a mismatch, not a
broker restarting at that moment: 0.3 s of back-off."""

TRANSIENT_REFUSALS = {"Server unavailable"}
"""CONNACK refusals (paho's names for MQTT 3.1.1's return codes) that a broker may lift by itself:
tried again with back-off. Every other refusal ends the command (BrokerRefused)."""


_FEED_ERRORS = (ArithmeticError, LookupError, TypeError, ValueError)
"""What a decoded batch that is still unusable raises in numpy or the engine (Worker._drain)."""

SERVICE_EVERY = 200
"""Positions a worker publishes between reads of its socket during a tick (Mosquitto's per-client
queue, max_queued_messages, is 1,000 by default: a worker that stops reading for long loses batches)."""


class BrokerError(Error):
    """A broker address, login or CA that cannot be used."""


class BrokerRefused(BrokerError):
    """The broker said no for good (a login it refuses, a certificate we refuse, TLS against
    plaintext): trying again cannot help, so the command ends (exit 2) naming the cause and the fix."""


HOW_TO_GIVE_A_PASSWORD = f"--password-file FILE or ${PASSWORD_ENV}"

MAX_PASSWORD = 65_535
"""MQTT 3.1.1 section 3.1.3.5: the password is binary data of up to 65,535 bytes."""


@dataclass(frozen=True)
class Broker:
    """``mqtt://[USER@]HOST[:PORT][/PARTITIONS]`` or ``mqtts://`` (TLS, port 8883 by default).
    The user name and password are percent-decoded (``%40`` is ``@``); the password is better
    not in the URL at all (:meth:`login`). It never shows in ``repr`` or ``str``."""

    host: str
    port: int
    tls: bool
    partitions: int | None
    username: str | None = None
    password: str | None = field(default=None, repr=False)

    @classmethod
    def parse(cls, url: str) -> Broker:
        """The parts of a broker URL, each checked here: a bad one is a one-line error (exit 2), not
        a connection that can never succeed or a worker that subscribes to a billion partitions."""
        u = urlsplit(url if "://" in url else f"mqtt://{url}")
        shown = repr(redact(url))
        if u.scheme not in ("mqtt", "mqtts") or not u.hostname:
            raise BrokerError(f"{shown}: write mqtt://[USER@]HOST[:PORT][/PARTITIONS] (or mqtts:// for TLS)")
        if u.query or u.fragment:
            raise BrokerError(f"{shown}: a broker URL has no ?query or #fragment: mqtt://[USER@]HOST[:PORT][/PARTITIONS] "
                              f"(a password with '/', '?' or '#' goes in {HOW_TO_GIVE_A_PASSWORD}, or percent-encoded: "
                              "%2F, %3F, %23)")
        try:
            u.hostname.encode("idna")
        except UnicodeError:
            raise BrokerError(f"{shown}: {u.hostname!r} is not a host name") from None
        path = u.path.strip("/")
        if path and not (path.isascii() and path.isdigit() and 1 <= int(path) <= sitebus.MAX_PARTITIONS):
            raise BrokerError(f"{shown}: the path is the site's partition count, a whole number in "
                              f"1..{sitebus.MAX_PARTITIONS} (the same for every gateway and worker of the site)")
        try:
            port = u.port
        except ValueError:
            raise BrokerError(f"{shown}: the port is a number in 1..65535") from None
        if port == 0:
            raise BrokerError(f"{shown}: the port is a number in 1..65535 (leave it out for 1883, mqtts 8883)")
        port = port or (8883 if u.scheme == "mqtts" else 1883)
        user, password = (None if v is None else unquote(v) for v in (u.username, u.password))
        return cls(u.hostname, port, u.scheme == "mqtts", int(path) if path else None, user, password)

    def login(self, password_file: str | None = None, environ: Mapping[str, str] = os.environ) -> Broker:
        """This broker with the password from ``password_file`` (its first line) or, when neither
        it nor the URL gives one, from $RFHOMING_MQTT_PASSWORD: neither shows in ``ps``, unlike
        a URL's. A URL's password still works, with a warning that anyone on the machine can read it."""
        if password_file is not None:
            if self.password is not None:
                raise BrokerError(f"--password-file {password_file}: the broker URL has a password too; give it once "
                                  "(the file: a URL on the command line is visible to every user in ps)")
            try:
                with open(password_file, encoding="utf-8") as f:
                    mode = os.fstat(f.fileno()).st_mode
                    lines = f.read(MAX_PASSWORD + 2).splitlines()
            except (OSError, UnicodeDecodeError) as exc:
                raise BrokerError(f"--password-file {password_file}: cannot read it "
                                  f"({getattr(exc, 'strerror', None) or exc}): give a file holding the password "
                                  "on its first line") from None
            if not lines or not lines[0] or len(lines[0].encode()) > MAX_PASSWORD:
                raise BrokerError(f"--password-file {password_file}: its first line is not a password (empty, or "
                                  f"longer than {MAX_PASSWORD} characters): write the password on it")
            password = lines[0]
            if mode & 0o077:  # as ssh does for a private key: said, not refused (a shared machine's group may be one user)
                log.warning("--password-file %s can be read by other users (mode %03o): chmod 600 %s",
                            password_file, mode & 0o777, password_file)
        elif self.password is None and environ.get(PASSWORD_ENV) and self.username is not None:
            password = environ[PASSWORD_ENV]
        else:
            if self.password is not None:
                log.warning("the MQTT password is in the broker URL, which every user of this machine can read "
                            "(ps, /proc/PID/cmdline): give it with %s instead", HOW_TO_GIVE_A_PASSWORD)
            return self
        if self.username is None:
            raise BrokerError(f"a password ({'--password-file' if password_file else '$' + PASSWORD_ENV}) needs a "
                              "user name: write it in the broker URL, mqtt://USER@HOST[:PORT][/PARTITIONS]")
        return replace(self, password=password)

    def __str__(self) -> str:
        return f"{'mqtts' if self.tls else 'mqtt'}://{self.host}:{self.port}"


def _client(client_id: str, broker: Broker, ca_file: str | None = None) -> mqtt.Client:
    # MQTT 3.1.1: the bus needs nothing of 5 (wills, retained messages and QoS are 3.1.1's; shared
    # subscriptions were tried and rejected, docs/protocol.md), and paho unpacks 5's properties of
    # every received message in Python: a fifth of a worker's CPU per received batch, measured
    c = mqtt.Client(CallbackAPIVersion.VERSION2, client_id=client_id, protocol=mqtt.MQTTv311)
    if broker.username is not None:
        c.username_pw_set(broker.username, broker.password)
    if ca_file is not None and not broker.tls:
        raise BrokerError(f"--ca {ca_file}: the broker URL {broker} is plaintext MQTT; write mqtts:// for TLS "
                          "(or leave --ca out)")
    if broker.tls:
        try:
            c.tls_set(ca_certs=ca_file, cert_reqs=ssl.CERT_REQUIRED)
        except (OSError, ValueError) as exc:  # ssl.SSLError is an OSError: not PEM, no certificate in it
            raise BrokerError(f"--ca {ca_file}: cannot load it as a CA certificate "
                              f"({getattr(exc, 'strerror', None) or exc}): give the PEM file of the CA that "
                              "signed the broker's certificate") from None
    c.reconnect_delay_set(min_delay=RECONNECT_MIN_S, max_delay=RECONNECT_MAX_S)  # type: ignore[arg-type]  # paho's ints; it waits for any number of seconds
    c.connect_timeout = CONNECT_TIMEOUT_S
    return c


class Publisher:
    """One MQTT connection that publishes with a bounded buffer across broker outages.

    ``threaded`` (the default): paho's own network thread reads, writes and reconnects. Without it
    the owner calls :meth:`service` from its loop: a process that publishes thousands of messages a
    second (a worker, the emulated gateways) then spends up to a third less CPU per message
    (bench/site_bench.py "publish": 8-11 against 10-14 us in four runs, once the same), with no
    thread to wake per publish and no GIL handed back and forth; its reads also wait for its loop."""

    def __init__(self, broker: Broker, client_id: str, *, buffer: int = BUFFER_MESSAGES, keepalive: int = 10,
                 will: tuple[str, bytes] | None = None, ca_file: str | None = None, threaded: bool = True,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.broker = broker
        self.client = _client(client_id, broker, ca_file)
        self.client.max_queued_messages_set(buffer)  # QoS 1 messages (a worker's entry); QoS 0: _room()
        if will is not None:
            self.client.will_set(will[0], will[1], qos=1, retain=True)
        self._buffer: collections.deque[tuple[str, bytes, int, bool]] = collections.deque()
        self._cap = buffer
        self._lock = threading.Lock()
        self.connected = threading.Event()
        self.on_connect: list[Callable[[], None]] = []
        self.counters = {"published": 0, "buffered": 0, "dropped": 0, "unsent": 0, "connects": 0, "disconnects": 0,
                         "refused": 0}
        self._client_id = client_id
        self.failure: BrokerRefused | None = None
        """Set when the broker refused for good: no more tries; service() and wait_connected() raise it."""
        self._on_failure: list[Callable[[], None]] = []  # called once, on paho's thread when threaded
        self._failure_lock = threading.Lock()
        self._answered = False  # the broker answered this try's CONNECT (a CONNACK, yes or no)
        self._mismatches = 0  # tries in a row closed before any MQTT answer
        self._refusals = 0  # in the current streak: the first is logged, the rest counted
        self.caught_up = False
        """service() read everything that had arrived when it returned (False: READ_BURST more wait)."""
        self._away_since: float | None = time.monotonic()  # None while connected; the outage's first warning
        self._warned_away = self._warned_drop = False  # once per outage each
        self.client.on_connect = self._connected
        self.client.on_pre_connect = self._trying
        # paho calls on_connect_fail inside its "except OSError" around the try: exc_info is that error
        self.client.on_connect_fail = lambda client, userdata: self._unreachable(sys.exc_info()[1])
        self.client.on_disconnect = self._disconnected
        self.client.connect_async(broker.host, broker.port, keepalive=keepalive)
        self._clock = clock
        self._retry_at, self._delay = -math.inf, RECONNECT_MIN_S
        self._closing = False
        if threaded:
            self.client.loop_start()

    def service(self, timeout: float) -> None:
        """Run the network loop in the caller's thread for up to ``timeout`` s (threaded=False):
        what arrived is read (callbacks run here), what waits is written, and a lost broker is
        tried again 0.1 s doubling to 5 s later, as paho's thread would. An attempt counts from
        its start: a broker that answers and refuses only for now ("Server unavailable") is tried
        no more often than one that is away; only a login it accepts resets the delay. A refusal
        for good (a wrong password, a certificate we refuse, TLS against plaintext) raises
        :class:`BrokerRefused`, now and at every later call."""
        if self.failure is None:
            self._service(timeout)
        if self.failure is not None:
            raise self.failure

    def _service(self, timeout: float) -> None:
        if self.client.socket() is None:
            now = self._clock()
            if now < self._retry_at:
                time.sleep(min(timeout, self._retry_at - now))
                return
            self._retry_at, self._delay = now + self._delay, min(RECONNECT_MAX_S, 2 * self._delay)
            try:
                self.client.reconnect()
            except OSError as exc:
                self._unreachable(exc)
                log.debug("broker not reachable (%s): again in %.1f s", exc, self._retry_at - now)
                return
        self.client.loop(timeout)
        if self._buffer and self.connected.is_set():
            with self._lock:
                self._drain()  # what waited for paho's queue to shrink (_room)
        # paho's loop (and loop_read, whatever max_packets says) reads one packet per call: read
        # what else is waiting now, or a worker falls behind the thousands of batches a second
        for _ in range(READ_BURST):
            sock = self.client.socket()
            if sock is None or not (getattr(sock, "pending", lambda: 0)() or select.select([sock], [], [], 0)[0]):
                self.caught_up = True
                break
            self.client.loop_read()
        else:
            self.caught_up = False

    def wait_connected(self, timeout: float) -> bool:
        """Wait for the broker (servicing the connection when there is no paho thread)."""
        end = time.monotonic() + timeout
        while not self.connected.is_set() and time.monotonic() < end:
            if self.client._thread is None:  # noqa: SLF001 (paho has no public "is threaded")
                self.service(0.05)
            else:
                self.connected.wait(0.05)
            if self.failure is not None:
                raise self.failure
        return self.connected.is_set()

    def _trying(self, client: mqtt.Client, userdata: object) -> None:
        """paho's on_pre_connect: a new try, not answered yet."""
        self._answered = False

    def when_refused(self, hook: Callable[[], None]) -> None:
        """Call ``hook`` once when the broker refuses for good (on paho's thread when threaded), or
        at once if it has already: a refusal that came before the hook is not missed."""
        with self._failure_lock:
            if self.failure is None:
                self._on_failure.append(hook)
                return
        hook()

    def _fail(self, why: str) -> None:
        """The broker refused for good: no more tries (paho's thread ends), the owner is told."""
        with self._failure_lock:
            if self.failure is not None:
                return
            self.failure = BrokerRefused(why)
            hooks, self._on_failure = self._on_failure, []
        self.client.disconnect()
        for hook in hooks:
            hook()

    def _mismatch(self, what: str, fix: str) -> None:
        """A try the broker took and closed before any MQTT answer: MISMATCH_TRIES in a row fail."""
        self._mismatches += 1
        if self._mismatches >= MISMATCH_TRIES:
            self._fail(f"{what.format(n=self._mismatches)}: {fix}")

    def _unreachable(self, exc: BaseException | None) -> None:
        """A try to reach the broker failed. A certificate we refuse, or a TLS handshake the broker
        breaks off (a plaintext port), cannot get better; anything else (nothing listens, a
        timeout, no route) is an outage: said once, as a warning (nothing is published
        meanwhile), the rest at debug level."""
        b = self.broker
        if isinstance(exc, ssl.SSLCertVerificationError):
            self._fail(f"the TLS certificate of the broker {b} was not accepted ({exc.verify_message}): give the CA "
                       "that signed it with --ca PEM (without --ca, the system's CAs), and a host name in the URL "
                       "that the certificate names")
            return
        if b.tls and isinstance(exc, (ssl.SSLError, ConnectionResetError, ConnectionAbortedError, BrokenPipeError)):
            self._mismatch(f"the broker {b} broke off the TLS handshake {{n}} times in a row ({exc})",
                           "is this port plaintext MQTT? write mqtt:// for it, or the port of the broker's TLS "
                           "listener (usually 8883)")
            return
        self._mismatches = 0
        if not self._warned_away:
            self._warned_away = True
            log.warning("MQTT broker %s not reachable%s: nothing is published; messages wait in a buffer of %d "
                        "(the oldest dropped when it is full) and the broker is tried again every %g..%g s. "
                        "Check that the broker runs and the URL's host and port", self.broker,
                        f" ({exc})" if exc else "", self._cap, RECONNECT_MIN_S, RECONNECT_MAX_S)

    def _refused(self, name: str) -> str:
        """Why the broker's CONNACK ``name`` (paho's name for the 3.1.1 return code) ends the command."""
        b = self.broker
        if name in ("Bad user name or password", "Not authorized"):
            if b.username is None:
                return (f"the broker {b} refused an anonymous login ({name}): give a user in the URL, "
                        f"mqtt://USER@HOST..., and its password with {HOW_TO_GIVE_A_PASSWORD}")
            return (f"the broker {b} refused the login of user {b.username!r} ({name}): check the user name and "
                    f"the password ({HOW_TO_GIVE_A_PASSWORD}; in a URL, percent-encoded)")
        if name == "Client identifier not valid":
            return (f"the broker {b} refused the client id {self._client_id!r} ({name}): give this gateway or "
                    "worker another name (--name, --id)")
        if name == "Unsupported protocol version":
            return (f"the broker {b} does not speak MQTT 3.1.1 ({name}): the site bus needs a broker that does "
                    "(Mosquitto 1.3 or later, for one)")
        return f"the broker {b} refused the connection ({name}): its log says why"

    def _connected(self, client: mqtt.Client, userdata: object, flags: object, reason: object,
                   props: object) -> None:
        self._answered = True
        if getattr(reason, "is_failure", False):
            self.counters["refused"] += 1
            name = reason.getName() if isinstance(reason, ReasonCode) else str(reason)
            if name not in TRANSIENT_REFUSALS:
                self._fail(self._refused(name))
                return
            self._refusals += 1
            (log.warning if self._refusals == 1 else log.debug)(
                "broker refused the connection: %s (tried again with back-off; further refusals are counted)", reason)
            return
        self._refusals, self._mismatches, self._delay = 0, 0, RECONNECT_MIN_S
        self.counters["connects"] += 1
        if self._warned_away and self._away_since is not None:
            log.warning("MQTT broker %s reached after %.1f s away; %d messages waiting are sent now, %d dropped "
                        "so far", self.broker, time.monotonic() - self._away_since, len(self._buffer),
                        self.counters["dropped"])
        self._away_since, self._warned_away, self._warned_drop = None, False, False
        for hook in self.on_connect:
            hook()
        with self._lock:
            self.connected.set()
            self._drain()

    def _room(self) -> bool:
        """Whether paho may take another message. paho bounds its queue (max_queued_messages) for
        QoS > 0 only; every QoS 0 packet (each batch and position) goes to its deque ``_out_packet``
        (private, paho-mqtt 2.2 Client._packet_queue), unbounded, while a slow broker reads less
        than is published. Its length is the only measure paho gives of what waits."""
        return len(self.client._out_packet) < self._cap  # noqa: SLF001

    def _drain(self) -> None:
        """Send what was buffered, oldest first, while paho has room and takes it (the lock is held)."""
        while self._buffer and self._room():
            topic, payload, qos, retain = self._buffer[0]
            if self.client.publish(topic, payload, qos=qos, retain=retain).rc != mqtt.MQTT_ERR_SUCCESS:
                return
            self._buffer.popleft()
            self.counters["published"] += 1

    def _disconnected(self, client: mqtt.Client, userdata: object, flags: object, reason: object,
                      props: object) -> None:
        was = self.connected.is_set()
        self.connected.clear()
        self.counters["disconnects"] += 1
        if not (was or self._answered or self._closing or self.failure) and str(reason) != "Keep alive timeout":
            self._mismatch(f"the broker {self.broker} closed the connection before answering the MQTT login {{n}} "
                           "times in a row", "is this a TLS port? write mqtts:// (with --ca PEM) for it; else the "
                           "broker's log says why (max_connections, for one)")
        if was and not self._closing:
            self._away_since, self._warned_away = time.monotonic(), True
            log.warning("lost the MQTT broker %s (%s): nothing is published; messages wait in a buffer of %d and "
                        "it is tried again every %g..%g s", self.broker, reason, self._cap, RECONNECT_MIN_S,
                        RECONNECT_MAX_S)

    def publish(self, topic: str, payload: bytes, qos: int = 0, retain: bool = False) -> None:
        with self._lock:
            if self.connected.is_set():
                self._drain()  # after a refusal while connected (paho saw the socket go first), or it would stall
                if not self._buffer and self._room() and self.client.publish(
                        topic, payload, qos=qos, retain=retain).rc == mqtt.MQTT_ERR_SUCCESS:
                    self.counters["published"] += 1
                    return
            if len(self._buffer) >= self._cap:
                self._buffer.popleft()
                self.counters["dropped"] += 1
                if not self._warned_drop:
                    self._warned_drop = True
                    log.warning("MQTT buffer full (%d messages, broker %s %s): the oldest are dropped from now on, "
                                "counted in \"dropped\"", self._cap, self.broker,
                                "away" if not self.connected.is_set() else "reading slower than we publish")
            self._buffer.append((topic, payload, qos, retain))
            self.counters["buffered"] += 1

    def close(self) -> None:
        """Send what waits if the broker is there (for 2 s at most), disconnect; never raises, so the
        owner's counters are printed whatever the broker does. What never went out is ``unsent``."""
        end = time.monotonic() + 2.0  # without paho's thread, what paho holds is written first (a bound)
        while self.client._thread is None and time.monotonic() < end and self.connected.is_set() and (  # noqa: SLF001
                self.client.want_write() or self._buffer):
            self.service(0.05)
        self._closing = True
        self.client.disconnect()
        self.client.loop_stop()
        self.counters["unsent"] = len(self._buffer)
        if self._buffer and self.failure is None:  # refused: the owner's error line says why
            log.warning("%d messages never reached the MQTT broker %s (it was away at the end)", len(self._buffer),
                        self.broker)


class Gateway:
    """A gateway's side: angle events of its anchors, sorted into partitions, sent in batches."""

    def __init__(self, publisher: Publisher, site: str, name: str, partitions: int, offset_s: float = 0.0) -> None:
        sitebus.check_level("site name", site)
        sitebus.check_level("gateway name", name)  # a worker refuses a batch whose "gw" is not one
        self.publisher, self.site, self.name, self.partitions, self.offset_s = publisher, site, name, partitions, offset_s
        self._rows: dict[int, list[sitebus.Row]] = {}
        self._part_of: dict[str, int] = {}
        self._seq = [0] * partitions
        self.events = 0

    def _partition(self, tag: str) -> int:
        part = self._part_of.get(tag)
        if part is None:
            if len(self._part_of) >= 1_000_000:  # a bound, not a cache policy: ids are cheap to hash again
                self._part_of.clear()
            part = self._part_of[tag] = sitebus.partition(tag, self.partitions)
        return part

    def add(self, t_host: float, anchor_id: str, tag: str, azimuth: float, elevation: float) -> None:
        self._rows.setdefault(self._partition(tag), []).append((t_host, anchor_id, tag, azimuth, elevation))
        self.events += 1

    def add_columns(self, t: np.ndarray, anchors: list[str], a: np.ndarray, tags: list[str], g: np.ndarray,
                    az: np.ndarray, el: np.ndarray) -> None:
        """Events as columns (event k: anchor ``anchors[a[k]]``, tag ``tags[g[k]]``; an emulated
        site's tens of thousands a second), without a Python call per event."""
        part_of = self._partition
        for row in zip(t.tolist(), map(anchors.__getitem__, a.tolist()), map(tags.__getitem__, g.tolist()),
                       az.tolist(), el.tolist()):
            self._rows.setdefault(part_of(row[2]), []).append(row)
        self.events += len(t)

    def on_bearing(self, reading: Bearing) -> None:
        """One anchor's reading (host/bearing.py) onto the bus, its azimuth in the batches'
        clockwise degrees (the board models' sign)."""
        self.add(reading.t, reading.anchor, reading.tag, reading.clockwise_deg, reading.elevation_deg or 0.0)

    def flush(self, now: float) -> None:
        """Publish each partition's events since the last flush (``now`` on this gateway's clock)."""
        step = sitebus.MAX_BATCH_EVENTS  # a worker parses a bounded payload (sitebus.MAX_PAYLOAD)
        for part, rows in self._rows.items():
            for k in range(0, len(rows), step):
                payload = sitebus.encode_angles(self.name, self._seq[part], now, self.offset_s, rows[k:k + step])
                self._seq[part] += 1
                self.publisher.publish(sitebus.angles_topic(self.site, part), payload)
        self._rows = {}


class Worker:
    """A locate worker: owns the partitions rendezvous hashing gives it among the live workers,
    merges its gateways' batches on one clock, fixes every tag per tick and publishes positions."""

    def __init__(self, site: Site, broker: Broker, *, worker_id: str, partitions: int,
                 rate_hz: float | None = None, reorder_s: float = 0.02, track: bool = True, ca_file: str | None = None,
                 clock: Callable[[], float] = time.time) -> None:
        sitebus.check_level("site name", site.name)
        sitebus.check_level("worker id", worker_id)
        if not 1 <= partitions <= sitebus.MAX_PARTITIONS:
            raise BrokerError(f"{partitions} partitions: a site has 1..{sitebus.MAX_PARTITIONS}")
        self.site, self.worker_id, self.partitions = site, worker_id, partitions
        self._anchor_id = {a.name: a.id for a in site.anchors}  # positions name anchors as the batches do
        self.period = 1.0 / (rate_hz or site.rate_hz)
        self.reorder_s = reorder_s
        self.clock = clock
        self.engine = BatchLocator(site, track=track, gate=INCONSISTENT_CHI2_PER_DOF)
        self._claims: dict[str, float] = {}  # another live worker -> until when (self.clock) its claim counts
        self._next_beat = -math.inf
        self._read_until = -math.inf  # (self.clock) everything that came before it was read
        self.owned: set[int] = set()
        self._inbox: collections.deque[tuple[float, str, bytes]] = collections.deque(maxlen=INBOX_MESSAGES)
        self._lock = threading.Lock()
        self._min_delay: dict[str, collections.deque[float]] = {}
        self._seq: dict[tuple[str, str], int] = {}
        self.latencies: collections.deque[float] = collections.deque(maxlen=200_000)
        self.tick_late: collections.deque[float] = collections.deque(maxlen=200_000)
        self.counters = {"batches": 0, "events": 0, "bad_payload": 0, "unfed": 0, "lost_batches": 0,
                         "inbox_dropped": 0, "positions": 0, "inconsistent": 0, "other_partition": 0,
                         "handovers": 0, "gateways_forgotten": 0, "bad_claims": 0, "claims_ignored": 0}
        self._me = sitebus.workers_topic(site.name, worker_id)
        self.pub = Publisher(broker, f"rfhoming-worker-{worker_id}", will=(self._me, sitebus.OFFLINE),
                             ca_file=ca_file, threaded=False)
        self.pub.client.on_message = self._message
        self.pub.on_connect.append(self._subscribe_all)
        self._next_tick: int | None = None

    @property
    def live(self) -> set[str]:
        """This worker and every other whose claim still counts."""
        with self._lock:
            return {self.worker_id, *self._claims}

    # -- the network thread ------------------------------------------------------------------
    def _subscribe_all(self) -> None:
        c = self.pub.client
        c.subscribe(sitebus.workers_topic(self.site.name, "+"), qos=1)
        now = self.clock()
        c.publish(self._me, sitebus.encode_claim(now), qos=1, retain=True)
        self._next_beat = now + sitebus.HEARTBEAT_S
        with self._lock:
            self.owned = set()
        self._assign()

    def _beat(self) -> None:
        """Every HEARTBEAT_S: make this worker's claim again, and forget the claims that ran out."""
        now = self.clock()
        if now < self._next_beat:
            return
        self._next_beat = now + sitebus.HEARTBEAT_S
        if self.pub.connected.is_set():
            self.pub.client.publish(self._me, sitebus.encode_claim(now), qos=1, retain=True)
        with self._lock:  # run out, and no renewal unread: a worker that stalled reads before it judges
            gone = [name for name, until in self._claims.items() if until <= self._read_until]
            for name in gone:
                del self._claims[name]
        if gone:
            log.info("worker %s: no claim of %s for %g s: taken for gone", self.worker_id, ", ".join(sorted(gone)),
                     sitebus.CLAIM_HEARTBEATS * sitebus.HEARTBEAT_S)
            self._assign()

    def _claim(self, name: str, payload: bytes, retained: bool, now: float) -> bool:
        """Take another worker's claim (or its "offline"); whether the live set changed. A claim
        counts from when it was made (no later than now: a clock ahead gains nothing) for its
        heartbeats; one already run out on arrival -- a retained claim of a worker long gone, a
        fake without a heartbeat, a clock far behind -- counts for nothing."""
        if name == self.worker_id:
            return False  # ours: made again at the next heartbeat, whatever the broker holds
        try:
            claim = sitebus.decode_claim(payload)
        except sitebus.PayloadError as exc:
            (log.warning if self.counters["bad_claims"] == 0 else log.debug)(
                "ignored a message on %s that is not a worker claim (%s); further ones are counted (bad_claims)",
                sitebus.workers_topic(self.site.name, name), exc)
            self.counters["bad_claims"] += 1
            return False
        with self._lock:
            was = name in self._claims
            if claim is None:
                self._claims.pop(name, None)
                return was
            made, lasts = claim
            until = min(made, now) + lasts
            if until <= now:
                self._claims.pop(name, None)
                self.counters["claims_ignored"] += 1
                (log.debug if retained or self.counters["claims_ignored"] > 1 else log.warning)(
                    "the claim of worker %s was made %.1f s before it arrived, more than its %g s: not counted (its "
                    "clock behind this one's? keep the workers' clocks in step, NTP)", name, now - made, lasts)
                return was
            if not was and len(self._claims) >= MAX_WORKERS:
                self.counters["claims_ignored"] += 1
                return False
            self._claims[name] = until
            return not was

    def _assign(self) -> None:
        with self._lock:
            live = {self.worker_id, *self._claims}
            want = {p for p in range(self.partitions) if sitebus.owner(p, live) == self.worker_id}
            gained, lost = want - self.owned, self.owned - want
            self.owned = want
        if gained or lost:
            self.counters["handovers"] += 1
            log.info("worker %s: partitions %s (gained %s, lost %s)", self.worker_id, sorted(want), sorted(gained),
                     sorted(lost))
        c = self.pub.client
        for p in sorted(gained):
            c.subscribe(sitebus.angles_topic(self.site.name, p), qos=0)
        for p in sorted(lost):
            c.unsubscribe(sitebus.angles_topic(self.site.name, p))

    def _message(self, client: mqtt.Client, userdata: object, msg: mqtt.MQTTMessage) -> None:
        now = self.clock()
        topic = msg.topic
        if topic.startswith(f"rfhoming/{self.site.name}/workers/"):
            if self._claim(topic.rsplit("/", 1)[1], bytes(msg.payload), bool(msg.retain), now):
                self._assign()
            return
        if len(self._inbox) == self._inbox.maxlen:
            self.counters["inbox_dropped"] += 1
        self._inbox.append((now, topic, bytes(msg.payload)))

    # -- the worker's own thread ----------------------------------------------------------------
    def _drain(self) -> None:
        """Decode what arrived and feed it to the engine as one set of arrays (numpy's cost per
        call, not per batch: a site's gateways send thousands of small batches a second)."""
        batches, bases = [], []
        while self._inbox:
            recv, topic, payload = self._inbox.popleft()
            try:
                batch = sitebus.decode_angles(payload)
            except sitebus.PayloadError as exc:
                (log.warning if self.counters["bad_payload"] == 0 else log.debug)(
                    "dropped a message on %s that is not an angle batch (%s); further ones are counted "
                    "(bad_payload)", topic, exc)
                self.counters["bad_payload"] += 1
                continue
            self.counters["batches"] += 1
            key = (batch.gateway, topic)
            last = self._seq.pop(key, None)
            if last is not None and batch.seq > last + 1:
                self.counters["lost_batches"] += batch.seq - last - 1
            self._seq[key] = batch.seq  # (re)inserted: the dicts run from least to most lately heard
            # clock: worker time = gateway time + the least (receive - sent) seen lately, which is the
            # true offset plus the least network delay (NTP's minimum filter; docs/protocol.md)
            delays = self._min_delay.pop(batch.gateway, None) or collections.deque(maxlen=OFFSET_SAMPLES)
            self._min_delay[batch.gateway] = delays
            delays.append(recv - (batch.sent - batch.offset_s))
            self._forget_gateways()
            batches.append(batch)
            bases.append(batch.t0 + min(delays) - batch.offset_s)
        if not batches:
            return
        try:
            self._feed(batches, bases)
        except _FEED_ERRORS:
            # defence in depth (the decoder bounds every field): a batch it let through that numpy
            # or the engine cannot take costs only itself, not the others of this drain
            for batch, base in zip(batches, bases):
                try:
                    self._feed([batch], [base])
                except _FEED_ERRORS as exc:
                    self.counters["bad_payload"] += 1
                    (log.warning if self.counters["unfed"] == 0 else log.debug)(
                        "dropped a batch of %s the decoder passed (%s: %s); further ones are counted", batch.gateway,
                        type(exc).__name__, exc)
                    self.counters["unfed"] += 1

    def _forget_gateways(self) -> None:
        """Past MAX_GATEWAYS, forget the gateway heard from least lately (its offset and sequences)."""
        while len(self._min_delay) > MAX_GATEWAYS:
            gone = next(iter(self._min_delay))
            del self._min_delay[gone]
            self.counters["gateways_forgotten"] += 1
        while len(self._seq) > MAX_GATEWAYS * max(1, len(self.owned)):
            del self._seq[next(iter(self._seq))]

    def _feed(self, batches: list[sitebus.AngleBatch], bases: list[float]) -> None:
        sizes = np.array([len(b.dt_us) for b in batches])
        n = int(sizes.sum())
        chain = itertools.chain.from_iterable

        def column(name: str, dtype: type) -> np.ndarray:
            return np.fromiter(chain(getattr(b, name) for b in batches), dtype, n)

        a_off = np.repeat(np.cumsum([0] + [len(b.anchors) for b in batches[:-1]]), sizes)
        g_off = np.repeat(np.cumsum([0] + [len(b.tags) for b in batches[:-1]]), sizes)
        t = np.repeat(np.array(bases), sizes) + column("dt_us", np.int64) * 1e-6
        self.engine.feed_columns(t, list(chain(b.anchors for b in batches)), column("a", np.int64) + a_off,
                                 list(chain(b.tags for b in batches)), column("g", np.int64) + g_off,
                                 column("az", float), column("el", float))
        self.counters["events"] += n

    def step(self) -> float:
        """Run every tick that is due, on what arrived before it; seconds until the next one.
        What arrives between ticks waits in the inbox (it is stamped on arrival, for the clock
        offsets): one feed per tick, not one per message."""
        now = self.clock()
        if self._next_tick is None:
            self._next_tick = math.ceil(now / self.period)
        while (due := self._next_tick * self.period + self.reorder_s) <= now:  # tick k at k periods: no drift
            self.tick_late.append(self.clock() - due)  # > a period: this worker does not keep up
            self._drain()
            self._tick(round(self._next_tick * self.period, 9))
            self._next_tick += 1
            self._beat()  # a worker catching up on ticks still makes its claim
        return max(0.0, self._next_tick * self.period + self.reorder_s - self.clock())

    def _tick(self, t: float) -> None:
        with self._lock:
            owned = set(self.owned)
        site = self.site.name
        fixes = self.engine.tick(t, only_new=True)
        self._service(0.0)  # read what came meanwhile: the broker drops what queues past its limit
        for k, f in enumerate(fixes):
            if k % SERVICE_EVERY == SERVICE_EVERY - 1:
                self._service(0.0)
            if not f.new:
                continue  # nothing new of this tag since its last position: that one stands
            if sitebus.partition(f.tag, self.partitions) not in owned:
                self.counters["other_partition"] += 1  # a partition handed away: its tags age out
                continue
            now = self.clock()
            self.latencies.append(now - f.newest)
            ids = self._anchor_id
            self.pub.publish(sitebus.positions_topic(site, f.tag), sitebus.position_payload(
                site, t, f.tag, f.fix.point, f.fix.covariance, [ids[a] for a in f.fix.used],
                [ids[a] for a in f.fix.rejected], f.quality, self.worker_id, latency_s=now - f.newest,
                inconsistent=self._inconsistent(f.tag, f.quality) if f.inconsistent else None))
            self.counters["positions"] += 1

    def _inconsistent(self, tag: str, quality: float) -> str:
        """Why a position is flagged (its ``inconsistent`` field); the first one is also a warning."""
        why = (f"chi2_per_dof {quality:.3g} > {self.engine.gate:g}: the anchors' angles disagree far beyond their "
               "sigmas (an anchor moved, strong reflections, or a publisher sending false angles); the raw fix, "
               "kept out of the track")
        if self.counters["inconsistent"] == 0:
            log.warning("tag %s: %s. Positions like it are published flagged \"inconsistent\", further ones counted "
                        "(inconsistent); if no anchor moved, check who may publish on the site bus (the broker's ACL, "
                        "docs/usage.md section 5c)", tag, why)
        self.counters["inconsistent"] += 1
        return why

    def _service(self, timeout: float) -> None:
        self.pub.service(timeout)
        if self.pub.caught_up:
            self._read_until = self.clock()

    def run(self, duration: float | None = None, stop: threading.Event | None = None) -> None:
        end = None if duration is None else self.clock() + duration
        stop = stop or threading.Event()
        while not stop.is_set() and (end is None or self.clock() < end):
            self._beat()
            self._service(min(self.step(), 0.05))

    def close(self) -> None:
        """Say "offline" if the broker is there (for 2 s at most: one that is away publishes the
        will instead), then close; never raises, with or without a broker."""
        if self.pub.connected.is_set():
            info = self.pub.client.publish(self._me, sitebus.OFFLINE, qos=1, retain=True)
            end = time.monotonic() + 2.0
            # is_published() raises unless the publish was queued (rc 0): checked first
            while (info.rc == mqtt.MQTT_ERR_SUCCESS and not info.is_published() and self.pub.connected.is_set()
                   and time.monotonic() < end):
                self.pub.service(0.05)
        self.pub.close()

    def health(self) -> dict[str, object]:
        def quantile(values: collections.deque[float], q: float) -> float | None:
            v = sorted(values)
            return round(v[min(len(v) - 1, int(q * len(v)))], 4) if v else None

        return {**self.counters, **{f"engine_{k}": v for k, v in self.engine.counters.items()},
                **{f"mqtt_{k}": v for k, v in self.pub.counters.items()},
                "partitions": sorted(self.owned), "latency_p50_s": quantile(self.latencies, 0.5),
                "latency_p99_s": quantile(self.latencies, 0.99), "tick_late_p50_s": quantile(self.tick_late, 0.5),
                "tick_late_p99_s": quantile(self.tick_late, 0.99)}
