"""The site bus against a broker that refuses, secrets that must not show, and peers that lie:
a login, a certificate or TLS against plaintext (and back) refused for good ends a
gateway or worker at once, with one line naming the cause and the fix, exit 2; a password with
``@ : / #`` works, from a file or the environment, and never shows in ps, logs or errors; fake
worker claims and a rogue gateway degrade a site visibly, not silently; the broker's ACL of
docs/usage.md keeps gateways off the workers' topics. Mosquitto (Debian's) is the broker, with
a password file and TLS with a CA made here; mosquitto_sub and mosquitto_pub, unmodified, are
the independent clients that say what the broker did."""

from __future__ import annotations

import json
import logging
import math
import signal
import subprocess
import time
from pathlib import Path
from types import SimpleNamespace
from urllib.parse import quote

import brokers
import numpy as np
import pytest
import rigs
from hypothesis import given
from hypothesis import strategies as st

from rfhoming.emulator.site import SiteScenario
from rfhoming.host.site import Anchor, Site
from rfhoming.protocol import sitebus

pytestmark = pytest.mark.skipif(not (brokers.MOSQUITTO and brokers.SUB and brokers.PUB and brokers.PASSWD
                                     and brokers.OPENSSL),
                                reason="mosquitto, mosquitto-clients or openssl not installed (.ci/run installs them)")

PASSWORD = "p@ss:w/o#rd?%"
"""The gateway's password: every character a URL gives a meaning to."""
WORKER_PASSWORD = "w1 secret"
SITE = "site-16x40"
ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def site_broker(tmp_path_factory: pytest.TempPathFactory):
    """Mosquitto with logins only (users gw and w1) on a plaintext port and a TLS port."""
    folder = tmp_path_factory.mktemp("broker")
    tls = brokers.make_tls(folder)
    passwd = brokers.password_file(folder, {"gw": PASSWORD, "w1": WORKER_PASSWORD})
    plain, secure = brokers.free_port(), brokers.free_port()
    proc = brokers.start(folder, plain, f"allow_anonymous false\npassword_file {passwd}\n", tls_port=secure, tls=tls)
    files = folder / "files"
    files.mkdir()
    for name, text in (("gw.pass", PASSWORD), ("wrong.pass", "not-it")):  # owner-only, as a user keeps one
        (files / name).write_text(text + "\n")
        (files / name).chmod(0o600)
    yield SimpleNamespace(plain=plain, tls=secure, ca=tls.ca, other_ca=tls.other_ca, files=files)
    brokers.stop(proc)


def _sub(*args: str | int) -> list[str]:
    return [str(brokers.SUB), "-h", "127.0.0.1", *map(str, args)]


# -- refusals: exit 2, one line naming the cause and the fix ------------------------------------------------
REFUSALS = {
    # case: (URL, the password in $RFHOMING_MQTT_PASSWORD, our --ca, mosquitto_sub's options, what our line names)
    "wrong-password": ("mqtt://gw@127.0.0.1:{plain}/4", "not-it", None, ["-p", "{plain}", "-u", "gw", "-P", "not-it"],
                       "refused the login of user 'gw'"),
    "no-password": ("mqtt://127.0.0.1:{plain}/4", None, None, ["-p", "{plain}"], "refused an anonymous login"),
    "wrong-ca": ("mqtts://gw@127.0.0.1:{tls}/4", PASSWORD, "{other_ca}",
                 ["-p", "{tls}", "-u", "gw", "-P", PASSWORD, "--cafile", "{other_ca}"], "certificate"),
    "no-ca": ("mqtts://gw@127.0.0.1:{tls}/4", PASSWORD, None,
              ["-p", "{tls}", "-u", "gw", "-P", PASSWORD, "--capath", "/etc/ssl/certs"], "certificate"),
    "tls-to-plaintext": ("mqtts://gw@127.0.0.1:{plain}/4", PASSWORD, "{ca}",
                         ["-p", "{plain}", "-u", "gw", "-P", PASSWORD, "--cafile", "{ca}"], "TLS handshake"),
    "plaintext-to-tls": ("mqtt://gw@127.0.0.1:{tls}/4", PASSWORD, None, ["-p", "{tls}", "-u", "gw", "-P", PASSWORD],
                         "before answering the MQTT login"),
}


@pytest.mark.parametrize("command", ["worker", pytest.param("gateway", marks=pytest.mark.slow)])
@pytest.mark.parametrize("case", list(REFUSALS))
def test_a_refusal_ends_the_command_with_one_line_naming_it(case: str, command: str, site_broker, cli) -> None:
    """No --duration: each used to retry for ever (with --duration: exit 0 at its end; plaintext
    to the TLS port without a word). Mosquitto's own client, given the same login, CA and port,
    fails too (a non-zero exit, and not its time-out's 27: it never connected)."""
    import os

    url, password, ca, theirs, names = REFUSALS[case]
    fill = {k: str(v) for k, v in vars(site_broker).items()}
    theirs = [a.format(**fill) for a in theirs]
    # plaintext to the TLS port, mosquitto_sub retries silently until its -W, then exits 255 (not 27:
    # it never connected); every other refusal ends it at once
    wait = "2" if case == "plaintext-to-tls" else "60"
    mosquitto_sub = subprocess.run([*_sub(*theirs), "-t", "x", "-C", "1", "-W", wait], capture_output=True,
                                   text=True, timeout=120)
    assert mosquitto_sub.returncode not in (0, 27), mosquitto_sub
    url = url.format(**fill)
    args = (["locate", SITE, "--from", url] if command == "worker" else ["gateway", "--emulate", SITE, "--broker", url])
    env = {k: v for k, v in os.environ.items() if k != "RFHOMING_MQTT_PASSWORD"}
    if password is not None:
        env["RFHOMING_MQTT_PASSWORD"] = password
    done = cli(*args, *(["--ca", ca.format(**fill)] if ca else []), env=env, timeout_s=120)  # a hang guard
    lines = done.stderr.strip().splitlines()
    assert done.returncode == 2 and len(lines) == 1, done.stderr
    prog = "locate" if command == "worker" else "gateway"
    assert lines[0].startswith(f"rfhoming {prog}: ") and names in lines[0], lines[0]
    assert PASSWORD not in done.stderr + done.stdout and quote(PASSWORD, safe="") not in done.stderr


def test_a_device_gateway_refused_by_the_broker_ends_at_once(site_broker, emulated, cli, tmp_path: Path) -> None:
    """``gateway --device`` publishes from paho's own thread while the drivers run on asyncio:
    the refusal there ends the drivers' run too (it retried for ever, exit 0 at --duration)."""
    world = emulated("s0-open", link_dir=tmp_path)
    done = cli("gateway", "--device", f"xplr-aoa:{world.path('aoa')}", "--site-name", "s", "--broker",
               f"mqtt://gw@127.0.0.1:{site_broker.plain}/4", "--password-file", site_broker.files / "wrong.pass",
               timeout_s=120)
    errors = [line for line in done.stderr.splitlines() if not line.startswith("{")]  # the drivers' counters
    assert done.returncode == 2 and len(errors) == 1 and "refused the login of user 'gw'" in errors[0], done.stderr


def test_a_threaded_publisher_stops_trying_and_says_so_once(site_broker) -> None:
    """paho's own thread (a device gateway's): a wrong password is tried once, then the thread
    ends, ``failure`` holds the one-line reason and a ``when_refused`` hook is called once, even
    one added after the refusal (which may come first on a loaded machine)."""
    from rfhoming.host.sitebus import Broker, BrokerRefused, Publisher

    calls: list[str] = []
    pub = Publisher(Broker("127.0.0.1", site_broker.plain, False, None, "gw", "not-it"), "gw-threaded")
    pub.when_refused(lambda: calls.append("failed"))
    try:
        with pytest.raises(BrokerRefused, match="refused the login of user 'gw'"):
            pub.wait_connected(60)  # a hang guard
        thread = pub.client._thread
        if thread is not None:
            thread.join(30)
        pub.when_refused(lambda: calls.append("late"))  # after the refusal: called at once
        assert pub.client._thread is None and calls == ["failed", "late"] and pub.counters["refused"] == 1
    finally:
        pub.close()


def test_the_ca_file_is_named_when_it_cannot_be_used(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """``--ca /nonexistent.pem`` said "No such file or directory" and named no file."""
    from rfhoming.cli.main import main

    (tmp_path / "not.pem").write_text("not a certificate\n")
    for ca in ("/nonexistent.pem", str(tmp_path / "not.pem")):
        assert main(["locate", SITE, "--from", "mqtts://127.0.0.1:1/4", "--ca", ca]) == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and f"--ca {ca}" in err, err
    assert main(["locate", SITE, "--from", "mqtt://127.0.0.1:1/4", "--ca", "/nonexistent.pem"]) == 2
    assert "mqtts://" in capsys.readouterr().err


# -- passwords: percent-decoded, from a file or the environment, never shown ---------------------------------
def test_credentials_in_a_url_are_percent_decoded_and_never_shown() -> None:
    from rfhoming.host.sitebus import Broker

    b = Broker.parse(f"mqtt://g%40w:{quote(PASSWORD, safe='')}@127.0.0.1/4")
    assert (b.username, b.password) == ("g@w", PASSWORD)
    assert PASSWORD not in repr(b) + str(b) and "%40" not in repr(b)


def test_where_a_password_comes_from(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    from rfhoming.host.sitebus import Broker, BrokerError

    pw = tmp_path / "pw"
    pw.write_text(PASSWORD + "\n")
    env = {"RFHOMING_MQTT_PASSWORD": "from-env"}
    user = Broker.parse("mqtt://gw@h/4")
    assert user.login(str(pw), env).password == PASSWORD  # the file wins over the environment
    assert user.login(None, env).password == "from-env"
    assert Broker.parse("mqtt://h/4").login(None, env).password is None  # anonymous: the environment unused
    with caplog.at_level(logging.WARNING, logger="rfhoming.host.sitebus"):
        assert Broker.parse("mqtt://gw:url@h/4").login(None, env).password == "url"  # the URL's, with a warning
    assert "(ps, /proc/PID/cmdline)" in caplog.text and "--password-file" in caplog.text
    for url, path, says in (("mqtt://gw:url@h/4", str(pw), "give it once"), ("mqtt://h/4", str(pw), "user name"),
                            ("mqtt://gw@h/4", str(tmp_path / "missing"), "missing"),
                            ("mqtt://gw@h/4", str(tmp_path), str(tmp_path))):
        with pytest.raises(BrokerError, match=says):
            Broker.parse(url).login(path, env)


@pytest.mark.parametrize("how", ["file", "env", "url"])
def test_a_password_with_url_characters_works_and_ps_never_shows_it(how: str, site_broker, spawn) -> None:
    """The emulated gateways log in over TLS with ``p@ss:w/o#rd?%`` (from --password-file, from
    $RFHOMING_MQTT_PASSWORD, percent-encoded in the URL); mosquitto_sub, logged in with the same
    password, reads a batch they published. While they run, no process of the machine shows the
    password in ps (the URL's form aside, which warns), nor their logs at -vv."""
    import os

    url = f"mqtts://gw@127.0.0.1:{site_broker.tls}/4"
    extra: list[str | Path] = []
    env = dict(os.environ)
    if how == "file":
        extra = ["--password-file", site_broker.files / "gw.pass"]
    elif how == "env":
        env["RFHOMING_MQTT_PASSWORD"] = PASSWORD
    else:
        url = f"mqtts://gw:{quote(PASSWORD, safe='')}@127.0.0.1:{site_broker.tls}/4"
    reader = rigs.Child(_sub("-p", site_broker.tls, "-u", "gw", "-P", PASSWORD, "--cafile", site_broker.ca,
                             "-t", f"rfhoming/{SITE}/angles/#", "-C", "1", "-W", "120"))
    with reader:
        time.sleep(0.5)  # mosquitto_sub subscribing; the gateways publish 50 batches a second until stopped
        gateway = spawn("-vv", "gateway", "--emulate", SITE, "--broker", url, "--ca", site_broker.ca, *extra, env=env)
        batch = json.loads(reader.line(deadline_s=120, what="a batch the gateways published"))
        assert reader.wait(60) == 0
    # the gateway still runs; mosquitto_sub takes its password only on its command line (-P): any
    # mosquitto_sub (ours has ended, another test run's may not have) is not rfhoming's to hide
    ps = "\n".join(line for line in subprocess.run(["ps", "-eww", "-o", "args="], capture_output=True, text=True,
                                                   timeout=60).stdout.splitlines()
                   if not line.startswith(("mosquitto_sub", "mosquitto_pub")))
    assert batch["v"] == 2 and batch["anchors"]
    assert PASSWORD not in ps
    assert (quote(PASSWORD, safe="") in ps) == (how == "url")
    gateway.send_signal(signal.SIGINT)
    assert gateway.wait(60) == 0
    out, err = gateway.output()
    assert PASSWORD not in out + err and json.loads(out.splitlines()[-1])["connects"] == 1
    assert (quote(PASSWORD, safe="") in err) is False
    assert ("--password-file FILE or $RFHOMING_MQTT_PASSWORD instead" in err) == (how == "url")


@pytest.mark.parametrize("args", [
    ["locate", SITE, "--from", "mqtt://gw:s3cret@127.0.0.1/0"],  # the site bus's own check, through argparse
    ["locate", SITE, "--from", "mqtt://gw:s3cr@t/w#x@127.0.0.1/4"],  # raw URL characters
    ["gateway", "--emulate", SITE, "--broker", "mqtt://gw:s3cret@127.0.0.1/4", "mqtt://gw:s3cret@h/4"],  # unrecognised
], ids=["partitions", "raw", "unrecognised"])
def test_errors_never_echo_a_password(args: list[str], capsys: pytest.CaptureFixture[str]) -> None:
    """argparse echoed the whole URL, password and all, in its one error line."""
    from rfhoming.cli.main import main

    try:
        code = main(args)
    except SystemExit as exc:  # argparse's own error
        code = int(exc.code or 0)
    err = capsys.readouterr().err
    assert code == 2 and "s3cr" not in err and "***@" in err, err


def test_log_lines_hide_a_urls_password() -> None:
    """Whoever logs a URL (paho, a library, a message of ours), the command line's log handler
    writes it with the password hidden."""
    from rfhoming.cli.main import _Redacting

    record = logging.LogRecord("any", logging.WARNING, __file__, 1, "lost %s", (f"mqtt://gw:{PASSWORD}@h:1883/4",), None)
    line = _Redacting("%(levelname)s %(message)s").format(record)
    assert line == "WARNING lost mqtt://gw:***@h:1883/4"


# -- peers that lie: fake worker claims, a rogue gateway ---------------------------------------------------
def _site(sc: SiteScenario, name: str = "w") -> Site:
    return Site(name, tuple(Anchor(a.name, a.id, None, a.position, 0.0, a.pitch_deg) for a in sc.anchors),
                sigma_deg=sc.sigma_deg)


def _offline_worker(sc: SiteScenario, now: list[float], partitions: int = 1):
    """A worker that never reaches a broker: what it publishes waits in its buffer, for the test to read."""
    from rfhoming.host.sitebus import Broker, Worker

    return Worker(_site(sc), Broker("127.0.0.1", 1, False, None), worker_id="w1", partitions=partitions,
                  clock=lambda: now[0])


def test_claims_count_for_their_heartbeats_and_nothing_else() -> None:
    """A plain "online" (what a worker used to retain, and 8 fake ones held a real worker to 0
    positions for 12 s), a claim older than its heartbeats, a non-finite or absurd one: none
    counts. A fresh one counts for 5 heartbeats from when it was made (no later than now), and
    runs out only once the worker has read what came meanwhile (a worker that stalled would
    otherwise drop every claim whose renewal waits unread); "offline" ends it at once."""
    sc = SiteScenario(4, 2, seed=1, clock_spread_s=0.0)
    now = [1_800_000_000.0]
    worker = _offline_worker(sc, now)
    lasts = sitebus.CLAIM_HEARTBEATS * sitebus.HEARTBEAT_S
    for name, payload in (("old-style", b"online"), ("nan", b'{"v":1,"state":"online","t":NaN,"heartbeat_s":1}'),
                          ("inf", b'{"v":1,"state":"online","t":1e999,"heartbeat_s":1}'),
                          ("absurd-beat", b'{"v":1,"state":"online","t":1800000000,"heartbeat_s":1e9}'),
                          ("text-t", b'{"v":1,"state":"online","t":"1800000000","heartbeat_s":1}'),
                          ("deep", b"[" * 5000)):
        assert not worker._claim(name, payload, True, now[0])
    assert worker.counters["bad_claims"] == 6
    assert not worker._claim("stale", sitebus.encode_claim(now[0] - lasts - 0.1), True, now[0])
    assert worker.counters["claims_ignored"] == 1
    assert worker._claim("fresh", sitebus.encode_claim(now[0] - 1.0), True, now[0])
    assert worker._claim("ahead", sitebus.encode_claim(now[0] + 3600), False, now[0])  # counted from now, not then
    assert worker.live == {"w1", "fresh", "ahead"}
    now[0] += lasts - 1.0
    worker._beat()
    assert worker.live == {"w1", "fresh", "ahead"}  # run out, but what came meanwhile is not read yet
    worker._read_until = now[0]  # (as service() sets it once it has read all that came)
    worker._next_beat = -math.inf
    worker._beat()
    assert worker.live == {"w1", "ahead"}
    assert worker._claim("ahead", sitebus.OFFLINE, False, now[0]) and worker.live == {"w1"}


@given(st.binary(max_size=300))
def test_any_bytes_are_a_claim_offline_or_a_payload_error(data: bytes) -> None:
    try:
        claim = sitebus.decode_claim(data)
    except sitebus.PayloadError:
        return
    assert claim is None or all(math.isfinite(x) for x in claim)


def _fake_claims(site: str, partitions: int) -> list[str]:
    """Names that, counted beside w1, would leave w1 owning no partition."""
    names: list[str] = []
    k = 0
    while any(sitebus.owner(p, {"w1", *names}) == "w1" for p in range(partitions)):
        if any(sitebus.owner(p, {"w1", *names, f"ghost{k}"}) == f"ghost{k}" for p in range(partitions)):
            names.append(f"ghost{k}")
        k += 1
    return names


def _publish(port: int, topic: str, payload: bytes, *login: str, retain: bool = True) -> None:
    subprocess.run([str(brokers.PUB), "-h", "127.0.0.1", "-p", str(port), *login, "-t", topic, "-s", "-q", "1",
                    *(["-r"] if retain else [])], input=payload, check=True, timeout=60)


def _positions_of_every_partition(port: int, site: str, partitions: int, *login: str) -> list[dict]:
    """Positions (mosquitto_sub) until one of each partition's tags came; a hang guard only."""
    seen: set[int] = set()
    out = []
    with rigs.Child(_sub("-p", port, *login, "-t", f"rfhoming/{site}/positions/#", "-W", "240")) as reader:
        while len(seen) < partitions:
            p = json.loads(reader.line(deadline_s=240, what=f"positions of partitions beyond {sorted(seen)}"))
            seen.add(sitebus.partition(p["tag"], partitions))
            out.append(p)
    return out


def test_retained_fake_claims_hold_no_partition(tmp_path: Path, spawn) -> None:
    """Retained claims under fake names, made before the worker starts: plain "online" ones (the
    issue's 8), and stamped ones made once. The worker publishes positions of every partition
    (mosquitto_sub reads them); before, it owned none of them while the fakes stood."""
    port = brokers.free_port()
    broker = brokers.start(tmp_path, port)
    try:
        fakes = _fake_claims(SITE, 4)
        for name in fakes:
            _publish(port, sitebus.workers_topic(SITE, name), b"online")
            _publish(port, sitebus.workers_topic(SITE, f"{name}-stamped"), sitebus.encode_claim(time.time() - 10))
        url = f"mqtt://127.0.0.1:{port}/4"
        worker = spawn("locate", SITE, "--from", url, "--id", "w1", "--rate", "20")
        spawn("gateway", "--emulate", SITE, "--broker", url)
        positions = _positions_of_every_partition(port, SITE, 4)
        worker.send_signal(signal.SIGINT)
        assert worker.wait(60) == 0
        counters = json.loads(worker.stdout().splitlines()[-1])
    finally:
        brokers.stop(broker)
    assert {p["worker"] for p in positions} == {"w1"}
    assert counters["partitions"] == [0, 1, 2, 3] and counters["bad_claims"] >= len(fakes)
    assert counters["claims_ignored"] >= len(fakes)


def _rogue(batch: bytes, rng: np.random.Generator) -> bytes:
    """The batch as a rogue gateway would send it: its anchors and tags, azimuths of +-60 degrees."""
    body = json.loads(batch)
    body["gw"], body["ang"][0] = "gw-rogue", rng.choice([-60, 60], len(body["ang"][0])).tolist()
    return json.dumps(body).encode()


def test_a_rogue_gateways_angles_are_flagged_not_tracked(caplog: pytest.LogCaptureFixture) -> None:
    """A gateway sending +-60 degree azimuths for the real anchors and tags drove chi2_per_dof from
    about 0.2 to 6 x 10^5 and z from 1.0 to 2.16 m while positions went out unflagged. Now: each
    such fix is published flagged ``inconsistent`` (why, in the position: valid against the
    schema), said once as a warning and counted; the tag's track is not moved by it, so the first
    positions after the rogue stops are where the tag is."""
    import jsonschema

    schema = json.loads((ROOT / "docs" / "schemas" / "position.schema.json").read_text())
    sc = SiteScenario(9, 1, seed=2, clock_spread_s=0.0, spacing_m=4.0)
    now = [1_800_000_000.0]
    worker = _offline_worker(sc, now)
    worker._assign()
    rng = np.random.default_rng(0)
    seq = 0
    phases: dict[str, list[dict]] = {}
    caplog.set_level(logging.WARNING, logger="rfhoming.host.sitebus")
    for phase, rogue in (("before", False), ("rogue", True), ("after", False)):
        for _ in range(40):  # 2 s in 0.05 s flushes
            t0 = now[0]
            now[0] += 0.05
            for g, rows in sc.events(t0, now[0]).items():
                if rows:
                    batch = sitebus.encode_angles(g, seq, now[0], 0.0, rows)
                    worker._inbox.append((now[0], sitebus.angles_topic("w", 0), batch))
                    if rogue:
                        worker._inbox.append((now[0], sitebus.angles_topic("w", 0), _rogue(batch, rng)))
                    seq += 1
            worker.step()
        phases[phase] = [json.loads(m[1]) for m in worker.pub._buffer if "/positions/" in m[0]]
        worker.pub._buffer.clear()
    truth = sc.truth(phases["after"][0]["t"])[0]
    assert phases["before"] and not any("inconsistent" in p for p in phases["before"])
    flagged = [p for p in phases["rogue"] if "inconsistent" in p]
    assert flagged, [p["chi2_per_dof"] for p in phases["rogue"]]
    for p in flagged:
        jsonschema.validate(p, schema)
        assert p["chi2_per_dof"] > 25 and "chi2_per_dof" in p["inconsistent"]
    assert worker.counters["inconsistent"] == len(flagged)
    warned = [r for r in caplog.records if "inconsistent" in r.getMessage()]
    assert len(warned) == 1 and warned[0].levelname == "WARNING"
    first_after = phases["after"][0]
    assert "inconsistent" not in first_after
    assert np.hypot(first_after["x"] - truth[0], first_after["y"] - truth[1]) < 1.0, (first_after, truth)


def test_an_inconsistent_fix_never_moves_the_track() -> None:
    """The engine's gate: a tag's angles all replaced by +-60 degree azimuths for a window gives a
    fix far beyond the gate, returned raw and flagged, while the tag's track stands as it was."""
    from rfhoming.host.estimation.batch import INCONSISTENT_CHI2_PER_DOF, BatchLocator

    sc = SiteScenario(9, 1, seed=2, clock_spread_s=0.0, spacing_m=4.0)
    loc = BatchLocator(_site(sc), track=True, gate=INCONSISTENT_CHI2_PER_DOF)
    rng = np.random.default_rng(0)
    t = 100.0
    for _ in range(20):
        loc.feed([row for rows in sc.events(t, t + 0.05).values() for row in rows])
        t += 0.05
        assert not any(f.inconsistent for f in loc.tick(t))
    flagged = 0
    for _ in range(10):  # longer than the window: in the end only the rogue's angles are left
        rows = [row for rows in sc.events(t, t + 0.05).values() for row in rows]
        loc.feed([(tt, a, tag, float(rng.choice([-60, 60])), el) for tt, a, tag, _, el in rows])
        t += 0.05
        state = (loc.tracker.t.copy(), loc.tracker.x.copy(), loc.tracker.p.copy())
        (fix,) = loc.tick(t)
        if fix.inconsistent:
            flagged += 1
            assert not fix.tracked and fix.quality > INCONSISTENT_CHI2_PER_DOF
            for before, after in zip(state, (loc.tracker.t, loc.tracker.x, loc.tracker.p)):
                np.testing.assert_array_equal(before, after)
    assert flagged >= 3 and loc.counters["inconsistent"] == flagged


# -- the broker's ACL of docs/usage.md -----------------------------------------------------------------------
ACL = ROOT / "docs" / "mosquitto" / "site-bus.acl"


def test_the_documented_acl_keeps_gateways_and_workers_to_their_topics(tmp_path: Path, spawn) -> None:
    """Mosquitto with docs/mosquitto/site-bus.acl (the file docs/usage.md shows): the gateway's
    login publishes batches, and the claims it makes for fake workers (live: stamped anew every
    half second) are dropped by the broker, so worker w1 still owns every partition and publishes
    positions of each; nor can w1 claim in w2's name; a reader sees positions and no batch."""
    assert ACL.read_text() in (ROOT / "docs" / "usage.md").read_text()
    assert any(sitebus.owner(p, {"w1", "w2"}) == "w2" for p in range(4))  # w2's claim, counted, would cost w1
    passwd = brokers.password_file(tmp_path, {"gw01": "gwpw", "w1": "w1pw", "reader": "rdpw"})
    port = brokers.free_port()
    broker = brokers.start(tmp_path, port, f"allow_anonymous false\npassword_file {passwd}\nacl_file {ACL}\n")
    try:
        for name, text in (("w1.pass", "w1pw"), ("gw.pass", "gwpw")):  # owner-only, as a user keeps one
            (tmp_path / name).write_text(text + "\n")
            (tmp_path / name).chmod(0o600)
        ghosts = _fake_claims(SITE, 4)
        stop = {"go": True}

        def claim_as_gateway() -> None:
            while stop["go"]:
                for name in ghosts:
                    _publish(port, sitebus.workers_topic(SITE, name), sitebus.encode_claim(time.time()),
                             "-u", "gw01", "-P", "gwpw")
                _publish(port, sitebus.workers_topic(SITE, "w2"), sitebus.encode_claim(time.time()),
                         "-u", "w1", "-P", "w1pw")
                time.sleep(0.5)

        import threading

        claimer = threading.Thread(target=claim_as_gateway, daemon=True)
        claimer.start()
        worker = spawn("locate", SITE, "--from", f"mqtt://w1@127.0.0.1:{port}/4", "--id", "w1", "--rate", "20",
                       "--password-file", tmp_path / "w1.pass")
        spawn("gateway", "--emulate", SITE, "--broker", f"mqtt://gw01@127.0.0.1:{port}/4", "--password-file",
              tmp_path / "gw.pass")
        positions = _positions_of_every_partition(port, SITE, 4, "-u", "reader", "-P", "rdpw")
        with rigs.Child(_sub("-p", port, "-u", "reader", "-P", "rdpw", "-t", f"rfhoming/{SITE}/#", "-v")) as reader:
            topics = [reader.line(deadline_s=120).split(" ", 1)[0] for _ in range(100)]  # batches come 50 a second
        stop["go"] = False
        claimer.join(60)
        worker.send_signal(signal.SIGINT)
        assert worker.wait(60) == 0
        counters = json.loads(worker.stdout().splitlines()[-1])
    finally:
        brokers.stop(broker)
    assert {p["worker"] for p in positions} == {"w1"} and counters["partitions"] == [0, 1, 2, 3]
    assert all("/positions/" in topic for topic in topics), sorted(set(topics))
