"""``rfhoming locate`` (a site worker with --from mqtt://) and ``rfhoming calibrate``: tag
positions from a site's fixed anchors."""

from __future__ import annotations

import argparse

from rfhoming.cli.args import (
    accel_psd,
    bus_name,
    duration,
    from_spec,
    height_sigma,
    is_broker,
    nonempty,
    output_file,
    path,
    rate_hz,
    reorder_s,
    seed,
    tag_height,
)
from rfhoming.cli.parsers import command
from rfhoming.cli.parsers.common import GROWING, add_login_arguments, add_port_defaults, add_ros2_option

LOCATE_HELP = """\
Locate tags from a site's fixed XPLR-AOA anchors (a site file: docs/usage.md, "Fixed anchors").
Every anchor's angle events are merged by host arrival time; at --rate (default: the site's
rate_hz) each tag has a position: a first fix (3-D rays, weighted, one bad anchor left out)
starts a tracker that every angle pair then updates, with each anchor's slow error as a state
and heavy-tailed reports (docs/estimation.md). Output: one JSON line per position
(kind "position": t, tag, x, y, z in metres, cov 3x3 in m^2, anchors used, rejected,
chi2_per_dof = the fix's quality, as on the site bus), and on exit one "summary" line (its
"estimate" says causal or smoothed). A capture of the anchors gives the same lines as the live run did; --smooth on a capture gives
RTS-smoothed positions instead, each marked "smoothed": true.

examples:
  rfhoming locate site.toml                                # the anchors' ports from the site
  rfhoming locate site.toml --duration 30 --capture run.pcapng
  rfhoming locate site.toml --from capture:run.pcapng      # the same positions, from the capture
  rfhoming locate site.toml --from capture:run.pcapng --smooth --loss cauchy   # after the fact
  rfhoming locate site.toml --from angles:angles.csv       # any board's angles (docs/usage.md, "An angles file")
  rfhoming locate site-64x1000 --from mqtt://127.0.0.1:1883/8 --id w1      # a site worker (below)
  rfhoming locate hall.toml --from mqtt+silabs://broker.local:1883         # Silicon Labs locators (below)

With --from mqtt+silabs://[USER@]BROKER[:PORT][/PREFIX] (mqtts+silabs:// = TLS; login as below)
locate reads the angles Silicon Labs' bt_aoa_host_locator publishes on PREFIX/angle/LOCATOR/TAG
(PREFIX silabs/aoa by default); each locator's address (its id without "ble-pd-") is a site
anchor's id (docs/hardware.md, "A Silicon Labs kit"; docs/protocol.md section 11).

the kit room of docs/sites, emulated (its first line printed, every link exists):
  mkdir -p /tmp/rfhoming-kit
  rfhoming emulate kit-room --link-dir /tmp/rfhoming-kit --duration 15 | { read -r _; rfhoming locate docs/sites/kit-room.toml --duration 10; }
"""

CALIBRATE_HELP = """\
Fit each anchor's angle corrections and write them, with its angle model, into the site file's
[anchors.NAME] tables (the rest of the file is kept as it was); report each anchor's angle
error before and after, each fitted parameter's standard deviation, and which parameters were
held and why (only what the points determine is fitted: e.g. no elevation when every point is
at one height). Results stay within the site file's limits, or nothing is written. The site
file is replaced whole (written as SITE.part, then renamed): a calibrate killed as it writes
leaves the old file, and SITE.part to remove.

With known points (--points FILE):

  [points]                           # tags that stay at one point all the recording
  CCF9578E0C01 = [2.0, 1.5, 0.8]     # x, y, z in metres, the site's frame

  [[dwell]]                          # one tag carried from point to point
  tag = "CCF9578E0D8A"
  position = [2.0, 1.5, 0.8]
  from_s = 10                        # seconds from the first angle event; leave both out and
  to_s = 40                          # the dwells (5 s or more still) are found, in order

Every anchor must see three or more points (spread out, not on one line through it).

Without (--self): tags walked over the whole room; each anchor's azimuth scale and bias (and
|azimuth| compression, where the data determine it) are fitted jointly with every epoch's
position (the scales' geometric mean is fixed to 1: an overall scale is not observable).
Elevation is held (its bias trades against the tag's height from anchors high on the walls):
--fit-elevation fits it too. The epochs are cut into 10 s blocks dealt into three folds, each
scored by a fit of the others: the calibration is written only when it beats the uncalibrated
site on these held-out epochs (and, with --fit-elevation, locate's tracker foresees the
recordings' reports better with it), else nothing is written and the verdict says why. A
parameter that runs to its bound or that the folds do not agree on is held at its default
("held", with the reason). Refused when the tags did not cover the room. One progress line on
stderr, one summary line on stdout (the verdict, each anchor's fit, what was held; --verbose:
each anchor's fit, sigmas and reasons, and each device's counters).

examples:
  rfhoming calibrate site.toml --points points.toml --duration 20
  rfhoming calibrate site.toml --points points.toml --from capture:cal.pcapng --dry-run
  rfhoming calibrate site.toml --points points.toml --azimuth-only --from capture:cal.pcapng
  rfhoming calibrate site.toml --self --from capture:walk1.pcapng --from capture:walk2.pcapng
  rfhoming calibrate site.toml --self --from angles:walk1.csv --from angles:walk2.csv
"""


RADIO_FIT_HELP = """\
Fit a radio profile to your own room's recordings, so that the emulator's XPLR-AOA anchors
behave as badly as yours (rfhoming emulate/demo/campaign --radio PROFILE; docs/emulator.md,
"Radio profiles"). Each --from is one recording of the site's anchors while the site's tag
(its first, or --tag) was walked over the room; the i-th --truth is the i-th --from's walk: a
waypoint file (one row per waypoint, arrival_ms,leave_ms,x_cm,y_cm, leave_ms NaN where the walker
did not stop: the layout of girolami_xplr_aoa/ground_truth/). Recordings past the last --truth,
or given --truth none, stand in for their own truth: the anchors are self-calibrated on them and
their track, located and smoothed, is taken as the walk; its own error then counts as the
radios', so the profile comes out harder than the room, never kinder. Every figure in PROFILE
names the recordings it came from. Walk the tag back over the same places (or record two walks)
so that an error that stays with a place can be told from one that wanders in time.

examples:
  rfhoming radio-fit site.toml --from capture:walk1.pcapng --truth walk1.csv -o room.toml
  rfhoming radio-fit site.toml --from capture:a.pcapng --truth a.csv --from capture:b.pcapng --truth b.csv -o room.toml
  rfhoming radio-fit site.toml --from capture:walk.pcapng -o room.toml      (no ground truth)
  rfhoming radio-fit site.toml --from angles:walk.csv --truth walk.csv -o room.toml
then rehearse with it: --radio room.toml on emulate, demo or campaign.
"""

WORKER_HELP = """\
With --from mqtt://[USER@]BROKER[:PORT][/PARTITIONS] (mqtts:// = TLS; USER@ a login, whose password
comes from --password-file or $RFHOMING_MQTT_PASSWORD: never the command line, which ps shows),
locate is a site worker: it subscribes to the partitions it owns among the live workers
(rendezvous hashing; a worker that goes, its will tells the others, who take its partitions),
measures each gateway's clock offset, fixes every tag per tick with the batched engine and
publishes each position as JSON on rfhoming/SITE/positions/TAG; on exit it prints one "worker"
line of counters. SITE is then a site file or an emulated site name (site-64x1000).

  rfhoming locate site-64x1000 --from mqtt://127.0.0.1:1883/8 --id w1
  rfhoming locate docs/sites/kit-room.toml --from mqtts://w1@broker.example/8 --password-file w1.pass --ca ca.pem
"""



def _locate(args: argparse.Namespace) -> int:
    """--from mqtt:// makes locate a site worker: the same command line, another job."""
    worker = args.sources and any(is_broker(s) for s in args.sources)
    return command("worker" if worker else "locate")(args)


def add_worker_arguments(p: argparse.ArgumentParser) -> None:
    """The worker's options on ``locate`` (used with --from mqtt:// only)."""
    w = p.add_argument_group("site worker (with --from mqtt://BROKER[/PARTITIONS])", WORKER_HELP)
    w.add_argument("--id", type=bus_name, default="w1", help="this worker's name among the site's workers (default w1)")
    w.add_argument("--reorder", type=reorder_s, default=0.02, metavar="S",
                   help="seconds a tick waits for late batches (default 0.02)")
    w.add_argument("--seed", type=seed, default=1, help="an emulated site's seed (default 1)")
    add_login_arguments(w)


def add_parsers(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    raw = argparse.RawDescriptionHelpFormatter
    for name, helptext, description in (
            ("locate", "positions of tags from a site's fixed AoA anchors", LOCATE_HELP),
            ("calibrate", "fit each fixed anchor's angle corrections from known points", CALIBRATE_HELP)):
        p = sub.add_parser(name, help=helptext, description=description, formatter_class=raw)
        p.add_argument("site", type=path, help="site file (TOML): anchors, their poses and ports, tags")
        p.add_argument("--from", dest="sources", type=from_spec, action="append", metavar="SPEC",
                       help="read these ports instead of the site's (repeatable), e.g. capture:run.pcapng, "
                            "or angles files: angles:FILE (CSV or JSON lines, docs/usage.md)")
        p.add_argument("--duration", type=duration, help="stop after this many seconds (a capture ends by itself)")
        add_port_defaults(p)
        if name == "locate":
            p.add_argument("--capture", type=output_file, help="also record every anchor's bytes to this pcapng file" + GROWING)
            p.add_argument("-o", "--output", type=output_file, help="write the JSON lines here instead of stdout" + GROWING)
            p.add_argument("--rate", type=rate_hz, help="positions per second per tag (default: the site's rate_hz)")
            p.add_argument("--no-track", action="store_true", help="raw fixes, no tracking filter")
            p.add_argument("--tracker", choices=("angles", "cv", "ekf"),
                           help="angles (default): every angle pair updates the track and each anchor's slow "
                                "error, heavy-tailed (made for real boards); cv: constant-velocity filter on the "
                                "fixes (cheapest); ekf: every angle pair updates the track, no error states")
            p.add_argument("--accel-psd", type=accel_psd,
                           help="tracking process noise: white acceleration, m^2/s^3 (default: 0.05 for angles, "
                                "chosen on real walks; 1 for cv and ekf)")
            p.add_argument("--smooth", action="store_true",
                           help="recordings only (--from capture:): RTS-smooth each tag's fixes over the whole "
                                "recording; positions are labelled \"smoothed\" (not causal)")
            p.add_argument("--loss", choices=("huber", "cauchy"), default="huber",
                           help="the fix's robust loss: huber (default; one bad anchor left out) or cauchy "
                                "(every anchor kept, each down-weighted by its miss)")
            p.add_argument("--height-sigma", type=height_sigma, metavar="M",
                           help="a tag's known height is a prior of this sigma (m), not a constraint")
            add_worker_arguments(p)
            add_ros2_option(p, "the anchors' angles and each tag's position (PoseWithCovarianceStamped and "
                               "PointStamped on /rfhoming/tag_<ID>/pose and /point, in map)")
            p.set_defaults(func=_locate)
        else:
            p.add_argument("--points", type=path, help="TOML: [points] TAGID = [x, y, z] and/or [[dwell]] tables")
            p.add_argument("--self", dest="self_calibrate", action="store_true",
                           help="no known points: fit each anchor's azimuth scale and bias from tags moving over "
                                "the whole room (give the recordings with --from capture:FILE)")
            p.add_argument("--azimuth-only", action="store_true",
                           help="fit azimuth (and yaw) only; elevation keeps scale 1 and bias 0")
            p.add_argument("--angle-model", choices=("auto", "spherical", "cone"),
                           help="the boards' angle model; auto (default): with --points the one with the smaller "
                                "residual, with --self each anchor's winner on held-out epochs (spherical, cone, "
                                "each with |azimuth| compression) if it beats the site file's by 3 percent")
            p.add_argument("--fit-elevation", action="store_true",
                           help="--self: also fit each anchor's elevation scale and bias where tags of known height "
                                "see 10+ deg of elevation; then written only if locate's tracker also foresees the "
                                "recordings' reports better with it (default: elevation held, reported under held)")
            p.add_argument("--height", type=tag_height, metavar="M",
                           help="--self: the height (m) of tags the site file gives none (else free about 1 m); "
                                "elevation is fitted only from tags of known height")
            p.add_argument("--dry-run", action="store_true", help="report the fit, leave the site file alone")
            p.add_argument("--verbose", action="store_true",
                           help="--self: also each anchor's fit (sigmas, held parameters and why, each angle model's "
                                "held-out rms) as JSON lines before the summary, and each device's counters")
            p.set_defaults(func=command("calibrate"))
    p = sub.add_parser("radio-fit", help="a radio profile for the emulator from your own room's recordings",
                       description=RADIO_FIT_HELP, formatter_class=raw)
    p.add_argument("site", type=path, help="site file (TOML): the anchors as mounted, and the walked tag's height")
    p.add_argument("--from", dest="sources", type=nonempty, action="append", required=True, metavar="SPEC",
                   help="a recording of the anchors (repeatable), e.g. capture:walk1.pcapng or angles:walk1.csv")
    p.add_argument("--truth", type=nonempty, action="append", default=[], metavar="FILE",
                   help="the waypoint file of the --from at the same place in the order (repeatable; none: "
                        "that recording stands in for its own truth)")
    p.add_argument("-o", "--output", type=output_file, required=True, metavar="PROFILE",
                   help="the profile to write (replaced whole)")
    p.add_argument("--name", type=nonempty, help="the profile's name (default: the output file's stem)")
    p.add_argument("--description", type=nonempty, metavar="TEXT",
                   help="what the profile is, in its [profile] table (default: how many recordings of which site)")
    p.add_argument("--tag", type=nonempty, metavar="ID", help="the walked tag (default: the site file's first)")
    p.add_argument("--height", type=tag_height, metavar="M", help="the walked tag's height (default: the site file's)")
    p.add_argument("--rssi-from", type=nonempty, metavar="PROFILE",
                   help="copy this radio profile's [rssi.NAME] tables (measured, or a profile file) into the one "
                        "written: radio-fit fits the XPLR-AOA's angles, not the RSSI")
    p.set_defaults(func=command("radio_fit"))
