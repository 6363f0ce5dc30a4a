"""Site scale: the batched engine's events/s per core, and the whole chain through Mosquitto.

engine: BatchLocator (fix + constant-velocity tracker) on an emulated site, CPU time per angle
    event, beside host/locate.py's per-tag Locator on the same events; accuracy of both vs truth.
chain: ``rfhoming gateway`` (emulated gateways) -> mosquitto -> 1 or 2 ``rfhoming locate SITE --from mqtt://``
    processes on this machine; per run the events/s offered and located, the workers' p99 latency
    from angle event to published position, and the CPU seconds of broker, gateways and workers
    per 10,000 events/s (psutil). The bench reads a sample of positions itself for accuracy.
publish: CPU per MQTT publish through host/sitebus.py's Publisher, threaded and serviced.

    python bench/site_bench.py [--json] [--rates 2,5,10] [--seconds 15]
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import psutil

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "src"))

from rfhoming.cli.commands.worker import emulated_site  # noqa: E402
from rfhoming.emulator.site import SiteScenario  # noqa: E402
from rfhoming.host.estimation.batch import BatchLocator  # noqa: E402
from rfhoming.host.locate import Locator  # noqa: E402
from rfhoming.host.drivers.aoa import bearing_of  # noqa: E402
from rfhoming.protocol.uconnect.items import AngleEvent  # noqa: E402

ENV = {**os.environ, "PYTHONPATH": str(ROOT / "src")}


def engine(name: str, seconds: float, reference_tags: int) -> dict[str, float]:
    sc = SiteScenario.named(name, clock_spread_s=0.0)  # on site time: offsets are the worker's (the chain's) part
    site = emulated_site(name, 1)
    batch = BatchLocator(site, track=True)
    chunks = [sorted(r for rs in sc.events(10 + k * 0.1, 10 + (k + 1) * 0.1).values() for r in rs)
              for k in range(int(seconds * 10))]
    n = 0
    cpu = 0.0
    errs = []
    same = []  # on the tags the per-tag path locates too
    keep = set(sc.tags[:reference_tags])
    for k, rows in enumerate(chunks):
        t = 10 + (k + 1) * 0.1
        c0 = time.process_time()
        batch.feed(rows)
        out = batch.tick(t)
        c1 = time.process_time()
        if k >= 10:  # after the tracker's start
            n += len(rows)
            cpu += c1 - c0
            truth = sc.truth(t)
            errs += [float(np.linalg.norm(f.fix.point - truth[int(f.tag[1:])])) for f in out]
            same += [e for f, e in zip(out, errs[-len(out):]) if f.tag in keep]
    # the per-tag path on the first reference_tags tags of the same events
    loc = Locator(site, track=True, tracker="cv", reorder_s=0.0)
    m = 0
    ref_cpu = 0.0
    ref_errs = []
    for k, rows in enumerate(chunks):
        sub = [r for r in rows if r[2] in keep]
        c0 = time.process_time()
        out = []
        for t, a, tag, az, el in sub:
            out += loc.feed(bearing_of(t, AngleEvent(tag, -50, az, el, 0, 37, a, "", 0)))
        c1 = time.process_time()
        if k >= 10:
            m += len(sub)
            ref_cpu += c1 - c0
            for p in out:
                ref_errs.append(float(np.linalg.norm(p.point - sc.truth(p.t, np.array([int(p.tag[1:])]))[0])))
    return {"site": name, "events": n, "batch_us_per_event": round(cpu / n * 1e6, 3),
            "batch_events_per_s_per_core": round(n / cpu), "batch_median_error_m": round(float(np.median(errs)), 3),
            "batch_p95_error_m": round(float(np.percentile(errs, 95)), 3),
            "batch_median_error_m_same_tags": round(float(np.median(same)), 3),
            "per_tag_tags": reference_tags, "per_tag_us_per_event": round(ref_cpu / m * 1e6, 2),
            "per_tag_median_error_m": round(float(np.median(ref_errs)), 3),
            "per_tag_p95_error_m": round(float(np.percentile(ref_errs, 95)), 3)}


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _broker(tmp: Path) -> tuple[subprocess.Popen, int]:
    port = _free_port()
    conf = tmp / "mosquitto.conf"
    conf.write_text(f"listener {port} 127.0.0.1\nallow_anonymous true\npersistence false\n")
    exe = shutil.which("mosquitto") or "/usr/sbin/mosquitto"
    proc = subprocess.Popen([exe, "-c", str(conf)], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    for _ in range(600):
        try:
            socket.create_connection(("127.0.0.1", port), timeout=1).close()
            return proc, port
        except OSError:
            time.sleep(0.05)
    raise RuntimeError("mosquitto did not start")


def _cli(*args: str) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "rfhoming.cli.main", *args], env=ENV, stdout=subprocess.PIPE,
                            text=True)


def _pressure() -> float | None:
    """The kernel's CPU pressure (share of the last 60 s some task waited for a CPU, %): the
    other tenants of a shared machine, recorded beside each latency."""
    try:
        line = Path("/proc/pressure/cpu").read_text().splitlines()[0]
    except OSError:
        return None
    return float(dict(kv.split("=") for kv in line.split()[1:])["avg60"])


def _cpu(proc: psutil.Process) -> float:
    t = proc.cpu_times()
    return t.user + t.system


def publish_cost(n: int = 20_000) -> dict[str, float]:
    """CPU per publish of a 416-byte batch (site-64x1000's mean) through ``Publisher``, with paho's
    network thread and with the caller servicing the connection (``threaded=False``)."""
    from rfhoming.host.sitebus import Broker, Publisher

    out = {}
    with tempfile.TemporaryDirectory() as tmp:
        broker, port = _broker(Path(tmp))
        for threaded in (True, False):
            pub = Publisher(Broker("127.0.0.1", port, False, None), f"bench-pub-{threaded}", threaded=threaded)
            pub.wait_connected(30)
            c0 = time.process_time()
            for _ in range(n):
                pub.publish("rfhoming/bench/angles/3", b"x" * 416)
            if not threaded:
                pub.service(0.0)
            time.sleep(0.5)  # paho's thread writes what is left (its CPU is the process's)
            out["threaded_us" if threaded else "serviced_us"] = round((time.process_time() - c0) / n * 1e6, 2)
            pub.close()
        broker.terminate()
        broker.wait(30)
    return out


def chain(name: str, tag_rate: float, workers: int, seconds: float, partitions: int, out_rate: float,
          flush: float = 0.02, reorder: float = 0.02) -> dict:
    import paho.mqtt.client as mqtt
    from paho.mqtt.enums import CallbackAPIVersion

    sc = SiteScenario.named(name, tag_rate_hz=tag_rate)
    with tempfile.TemporaryDirectory() as tmp:
        broker, port = _broker(Path(tmp))
        url = f"mqtt://127.0.0.1:{port}/{partitions}"
        ws = [_cli("locate", name, "--from", url, "--id", f"w{i + 1}", "--rate", str(out_rate),
                   "--reorder", str(reorder), "--duration", str(seconds + 4)) for i in range(workers)]
        sample = sc.tags[:: max(1, len(sc.tags) // 20)]
        errs: list[float] = []

        def on_message(client: object, userdata: object, msg: mqtt.MQTTMessage) -> None:
            p = json.loads(msg.payload)
            if p["t"] > t_start + 3:
                truth = sc.truth(p["t"], np.array([int(p["tag"][1:])]))[0]
                errs.append(float(np.linalg.norm(np.array([p["x"], p["y"], p["z"]]) - truth)))

        reader = mqtt.Client(CallbackAPIVersion.VERSION2, client_id="bench-reader", protocol=mqtt.MQTTv5)
        reader.on_message = on_message
        reader.connect("127.0.0.1", port)
        for tag in sample:
            reader.subscribe(f"rfhoming/{name}/positions/{tag}")
        reader.loop_start()
        time.sleep(2)  # the workers connect and share out the partitions
        t_start = time.time()
        gw = _cli("gateway", "--emulate", name, "--broker", url, "--tag-rate", str(tag_rate),
                  "--flush", str(flush), "--duration", str(seconds))
        bp = psutil.Process(broker.pid)
        b0 = _cpu(bp)
        wps = [psutil.Process(w.pid) for w in ws]
        w0 = [_cpu(p) for p in wps]
        gw.wait(seconds + 600)  # a hang guard; the gateway reports its own CPU (its loop's, not its imports')
        b_cpu = _cpu(bp) - b0
        w_cpu = []
        for p, c in zip(wps, w0):
            try:
                w_cpu.append(_cpu(p) - c)
            except psutil.Error:
                w_cpu.append(float("nan"))
        gw_line = json.loads(gw.stdout.read().strip().splitlines()[-1])
        health = [json.loads(w.communicate(timeout=120)[0].strip().splitlines()[-1]) for w in ws]
        reader.loop_stop()
        reader.disconnect()
        broker.terminate()
        broker.wait(30)
    rate = gw_line["events"] / seconds
    per10k = 10_000 / rate
    return {"site": name, "tag_rate_hz": tag_rate, "workers": workers, "seconds": seconds,
            "partitions": partitions, "output_hz": out_rate, "flush_s": flush, "reorder_s": reorder,
            "events_per_s": round(rate), "batches_per_s": round(gw_line["published"] / seconds), "gateway_behind": gw_line["behind"], "gateway_dropped": gw_line["dropped"],
            "located_events": sum(h["events"] for h in health),
            "lost_batches": sum(h["lost_batches"] for h in health),
            "positions_per_s": round(sum(h["positions"] for h in health) / seconds),
            "latency_p50_s": max(h["latency_p50_s"] or 0 for h in health),
            "latency_p99_s": max(h["latency_p99_s"] or 0 for h in health),
            "tick_late_p99_s": max(h["tick_late_p99_s"] or 0 for h in health),
            "partitions_per_worker": [h["partitions"] for h in health],
            "broker_cpu_per_10k": round(b_cpu / seconds * per10k, 3),
            "gateway_cpu_per_10k": round(gw_line["cpu_s"] / seconds * per10k, 3),
            "worker_cpu_per_10k": round(sum(w_cpu) / seconds * per10k, 3),
            "sample_median_error_m": round(float(np.median(errs)), 3) if errs else None,
            "load_avg_1min": round(os.getloadavg()[0], 2), "cpu_pressure_avg60_pct": _pressure()}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--site", default="site-64x1000")
    ap.add_argument("--rates", default="2,5,10", help="tag rates (Hz) for one worker")
    ap.add_argument("--two-workers-rate", type=float, default=10.0)
    ap.add_argument("--seconds", type=float, default=15.0)
    ap.add_argument("--partitions", type=int, default=8)
    ap.add_argument("--output-hz", type=float, default=20.0)
    ap.add_argument("--flush", type=float, default=0.02, help="the gateways' batch period (s)")
    ap.add_argument("--reorder", type=float, default=0.02, help="the workers' wait for late batches (s)")
    ap.add_argument("--skip-chain", action="store_true")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    results: dict[str, object] = {"engine": engine(args.site, 4.0, 50), "publish": publish_cost()}
    if not args.skip_chain:
        opts = (args.seconds, args.partitions, args.output_hz, args.flush, args.reorder)
        runs = [chain(args.site, float(r), 1, *opts) for r in args.rates.split(",")]
        runs.append(chain(args.site, args.two_workers_rate, 2, *opts))
        results["chain"] = runs
    if args.json:
        print(json.dumps(results, indent=1))
        return
    e = results["engine"]
    print(f"engine {e['site']}: batched fix+track {e['batch_us_per_event']} us/event = "
          f"{e['batch_events_per_s_per_core']:,} events/s per core (median error {e['batch_median_error_m']} m); "
          f"per-tag Locator {e['per_tag_us_per_event']} us/event; on its {e['per_tag_tags']} tags median error "
          f"{e['per_tag_median_error_m']} m per-tag, {e['batch_median_error_m_same_tags']} m batched")
    pc = results["publish"]
    print(f"publish (416 B, Mosquitto on loopback): {pc['threaded_us']} us CPU with paho's thread, "
          f"{pc['serviced_us']} us serviced by the caller")
    for r in results.get("chain", []):
        print(f"chain {r['site']} {r['tag_rate_hz']} Hz, {r['workers']} worker(s): {r['events_per_s']:,} events/s, "
              f"p50/p99 latency {r['latency_p50_s']}/{r['latency_p99_s']} s, CPU s per 10k events/s: broker "
              f"{r['broker_cpu_per_10k']}, gateways {r['gateway_cpu_per_10k']}, workers {r['worker_cpu_per_10k']}; "
              f"lost batches {r['lost_batches']}, gateway behind {r['gateway_behind']}, "
              f"ticks late p99 {r['tick_late_p99_s']} s, "
              f"median error {r['sample_median_error_m']} m; load {r['load_avg_1min']}, CPU pressure "
              f"{r['cpu_pressure_avg60_pct']} %")


if __name__ == "__main__":
    main()
