"""Angles files (host/angles_file.py, ``--from angles:FILE``): any board's reports as CSV or JSON
lines give locate the positions a +UUDF capture of the same reports gives; bad files are one
line naming file and row, exit 2."""

from __future__ import annotations

import csv
import json
import math
from pathlib import Path

import pytest

import rfhoming
from rfhoming.campaigns.kit import record
from rfhoming.cli.main import main
from rfhoming.host import site as sites
from rfhoming.host.angles_file import COLUMNS
from rfhoming.host.capture import CaptureWriter
from rfhoming.host.drivers.aoa import bearing_of

ROOT = Path(__file__).resolve().parents[1]
SITE = ROOT / "docs" / "sites" / "kit-room.toml"
KIT_ANCHOR = "CCF9578E0A01"


@pytest.fixture(scope="module")
def capture(tmp_path_factory) -> Path:
    """A +UUDF capture of the emulated kit room's anchors (6 s), as the boards printed it."""
    site = sites.load(SITE)
    names = {a.id: a.name for a in site.anchors}
    path = tmp_path_factory.mktemp("angles") / "kit.pcapng"
    writer = CaptureWriter(path)
    for name in names.values():
        writer.describe(name, kind="xplr-aoa")
    for e in record(seed=2, duration=6.0).events:
        line = (f'+UUDF:{e.tag},{int(e.rssi or 0)},{int(e.clockwise_deg)},{int(e.elevation_deg or 0)},-43,37,'
                f'"{e.anchor}","",{int(e.t * 1000)}\r\n')
        writer.tap(names[e.anchor], "in", 1000.0 + e.t, line.encode())
    writer.close()
    return path


def rows_of(capture: Path) -> list[dict[str, object]]:
    """The capture's angle events as an angles file's rows: REP 103 azimuth (the board's sign
    turned), through the same reading the driver makes."""
    out = []
    for got in rfhoming.read(f"capture:{capture}", kinds={"angle"}):
        r = bearing_of(got.t, got.item)
        out.append({"t": repr(r.t), "anchor": r.anchor, "tag": r.tag, "azimuth_deg": r.azimuth_deg,
                    "elevation_deg": r.elevation_deg, "rssi_dbm": r.rssi})
    return out


def write_csv(path: Path, rows: list[dict[str, object]]) -> Path:
    with path.open("w", newline="") as f:
        w = csv.DictWriter(f, COLUMNS)
        w.writeheader()
        w.writerows(rows)
    return path


def positions(capsys, *argv: str) -> list[dict]:
    capsys.readouterr()
    code = main(["locate", str(SITE), *argv])
    out, err = capsys.readouterr()
    assert code == 0, err
    lines = [json.loads(line) for line in out.splitlines()]
    return [p for p in lines if p["kind"] == "position"]


def test_a_capture_and_its_angles_file_give_the_same_positions(capture, tmp_path, capsys) -> None:
    rows = rows_of(capture)
    assert len(rows) > 500 and any(float(r["azimuth_deg"]) > 0 for r in rows)  # type: ignore[arg-type]
    from_capture = positions(capsys, "--from", f"capture:{capture}")
    from_csv = positions(capsys, "--from", f"angles:{write_csv(tmp_path / 'a.csv', rows)}")
    jsonl = tmp_path / "a.jsonl"
    jsonl.write_text("".join(json.dumps({**r, "t": float(r["t"])}) + "\n" for r in rows))  # type: ignore[arg-type]
    from_jsonl = positions(capsys, "--from", f"angles:{jsonl}")
    assert len(from_capture) > 20
    assert from_csv == from_capture and from_jsonl == from_capture


def test_an_angles_file_whose_angles_differ_gives_other_positions(capture, tmp_path, capsys) -> None:
    """The comparison above can fail: the board's sign left unturned moves every fix."""
    rows = [{**r, "azimuth_deg": -float(r["azimuth_deg"])} for r in rows_of(capture)]  # type: ignore[arg-type]
    mirrored = positions(capsys, "--from", f"angles:{write_csv(tmp_path / 'm.csv', rows)}")
    assert mirrored != positions(capsys, "--from", f"capture:{capture}")


def test_angles_over_the_whole_circle_and_empty_fields_are_read(tmp_path) -> None:
    from rfhoming.host.angles_file import load_angles

    path = write_csv(tmp_path / "w.csv", [
        {"t": 1.5, "anchor": "A1", "tag": "T", "azimuth_deg": 270, "elevation_deg": "", "rssi_dbm": ""},
        {"t": 1.0, "anchor": "A1", "tag": "T", "azimuth_deg": -180, "elevation_deg": 10, "rssi_dbm": -61}])
    first, second = load_angles(path, {"A1"})
    assert first.t == 1.0 and first.azimuth == pytest.approx(math.pi) and first.elevation_deg == 10
    assert first.rssi == -61 and second.azimuth == pytest.approx(-math.pi / 2)
    assert second.elevation is None and second.rssi is None


@pytest.mark.parametrize(("text", "message"), [
    ("t,anchor,tag,azimuth\n", "row 1: the header is"),
    ("t,anchor,tag,azimuth_deg,elevation_deg,rssi_dbm\n1.0,CCF9578E0A01,T,nan,,\n", "row 2: azimuth_deg = 'nan'"),
    ("t,anchor,tag,azimuth_deg,elevation_deg,rssi_dbm\n1.0,CCF9578E0A01,T,10,,\n2.0,CCF9578E0A01,T,10,95,\n",
     "row 3: elevation_deg = '95'"),
    ("t,anchor,tag,azimuth_deg,elevation_deg,rssi_dbm\n1e300,CCF9578E0A01,T,10,,\n", "row 2: t = '1e300'"),
    ("t,anchor,tag,azimuth_deg,elevation_deg,rssi_dbm\n1.0,NOSUCH,T,10,,\n", "row 2: anchor 'NOSUCH' is not in"),
    ("t,anchor,tag,azimuth_deg,elevation_deg,rssi_dbm\n1.0,CCF9578E0A01,T,10,\n", "row 2: 5 fields"),
    ("t,anchor,tag,azimuth_deg,elevation_deg,rssi_dbm\n1.0,CCF9578E0A01,,10,,\n", "row 2: tag is missing"),
    ("t,anchor,tag,azimuth_deg,elevation_deg,rssi_dbm\n" + "1" * 600 + "\n", "row 2: 600 characters"),
    ('{"t": 1.0, "anchor": "CCF9578E0A01", "tag": "T", "azimuth_deg": Infinity}\n', "row 1: azimuth_deg = 'Infinity'"),
    ('{"t": 1.0, "anchor": "CCF9578E0A01", "tag": "T", "azimuth_deg": 1}\n[1]\n', "row 2: a JSON list"),
    ('{"t": 1.0, "anchor": "CCF9578E0A01", "tag": "T", "azimuth_deg": 1, "az": 2}\n', "row 1: unknown key(s) az"),
    ("t,anchor,tag,azimuth_deg,elevation_deg,rssi_dbm\n", "has no rows"),
])
def test_bad_angles_files_are_one_line_naming_file_and_row(tmp_path, capsys, text, message) -> None:
    path = tmp_path / "bad.csv"
    path.write_text(text)
    for command in ("locate", "calibrate --self", f"radio-fit -o {tmp_path / 'p.toml'}"):
        capsys.readouterr()
        assert main([*command.split(), str(SITE), "--from", f"angles:{path}"]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        said = [line for line in err if str(path) in line]
        assert len(said) == 1 and message in said[0] and said[0] == err[-1], err
        assert "Traceback" not in "\n".join(err)


def test_an_angles_file_is_not_mixed_with_ports(tmp_path, capsys) -> None:
    path = write_csv(tmp_path / "a.csv", [{"t": 1.0, "anchor": KIT_ANCHOR, "tag": "T", "azimuth_deg": 1,
                                           "elevation_deg": "", "rssi_dbm": ""}])
    assert main(["locate", str(SITE), "--from", f"angles:{path}", "--from", "capture:x.pcapng"]) == 2
    assert "cannot be mixed" in capsys.readouterr().err


def test_readings_outside_an_anchors_field_of_view_are_refused_and_counted(tmp_path, capsys) -> None:
    """The kit room's anchors are XPLR-AOA boards (fov_deg 180 by default): a tag 150 degrees off
    the west anchor's boresight is no reading of it; as a circular array (fov_deg = 360) it is."""
    rows = [{"t": 1.0 + 0.05 * k, "anchor": KIT_ANCHOR, "tag": "CCF9578E0D8A", "azimuth_deg": az, "elevation_deg": 5,
             "rssi_dbm": ""} for k, az in enumerate([150, -91, 90, 10])]
    path = write_csv(tmp_path / "a.csv", rows)
    capsys.readouterr()
    assert main(["locate", str(SITE), "--from", f"angles:{path}"]) == 0
    out, err = capsys.readouterr()
    assert "field of view" in err and "refused: west 2" in err
    assert json.loads(out.splitlines()[-1])["events"] == 2
    circular = tmp_path / "site.toml"
    circular.write_text(SITE.read_text().replace('[anchors.west]\n', '[anchors.west]\nfov_deg = 360\nelevation = false\n'))
    assert main(["locate", str(circular), "--from", f"angles:{path}"]) == 0
    out, err = capsys.readouterr()
    assert "field of view" not in err and json.loads(out.splitlines()[-1])["events"] == 4


def test_an_anchor_without_elevation_drops_its_readings_elevation() -> None:
    west, _ = sites.parse({"site": {"name": "s"}, "anchors": {
        "west": {"id": KIT_ANCHOR, "position": [0, 0, 2], "fov_deg": 360, "elevation": False},
        "east": {"id": "CCF9578E0A02", "position": [9, 0, 2]}}}).anchors
    reading = bearing_of(1.0, rfhoming.AngleEvent("T", -50, 170, 12, 0, 37, KIT_ANCHOR, "", 0))
    assert west.fov_deg == 360 and west.admit(reading) == reading._replace(elevation=None)
    assert sites.Anchor("a", "A", None, (0.0, 0.0, 0.0)).admit(reading._replace(azimuth=math.radians(100))) is None


@pytest.mark.parametrize(("line", "message"), [("fov_deg = 0", "fov_deg = 0: expected a number from 1 to 360"),
                                               ("fov_deg = 400", "fov_deg = 400"),
                                               ('elevation = "no"', "elevation must be true or false")])
def test_bad_field_of_view_or_elevation_in_the_site_file(tmp_path, line, message) -> None:
    path = tmp_path / "site.toml"
    path.write_text(SITE.read_text().replace('[anchors.west]\n', f'[anchors.west]\n{line}\n'))
    with pytest.raises(sites.SiteError, match=message):
        sites.load(path)
