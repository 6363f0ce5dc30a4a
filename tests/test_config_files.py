"""Config and site files: every key is checked against the one schema (its dataclass field's
range and unit), and whatever a user writes -- a wrong type, NaN, a huge number, bytes that are
not UTF-8 -- is either accepted with sane values or refused with one line naming the key."""

from __future__ import annotations

import math
import re
import subprocess
import sys
from dataclasses import fields, is_dataclass
from pathlib import Path

import pytest
from hypothesis import given
from hypothesis import strategies as st

from rfhoming.host import site as sites
from rfhoming.host.homing.config import DEFAULT_TOML, SECTIONS, Config, ConfigError, load
from rfhoming.host.homing.schema import defaults_problems
from rfhoming.protocol.errors import Error

ROOT = Path(__file__).resolve().parent.parent
RFHOMING = [sys.executable, "-m", "rfhoming"]
KEY_LINE = re.compile(r"^(?P<key>[a-z_0-9]+) *= *(?P<value>.*?)(?P<comment> *#.*)?$")
NASTY = ['"x"', "nan", "inf", "-inf", "-5", "0", "1e300", "-1e300", "true", "[]", "{}", "[1, 2, 3]", '""',
         "5", "0.5", "-1", "1", "2", "[0.0, 0.0, 0.0, 0.0]", "[1, nan]", "9223372036854775807"]
"""Values a mutated file puts in place of one default: wrong types, non-finite, out of range
and a few plausible ones (which should be accepted where they fit)."""


def key_lines() -> list[tuple[int, str, str]]:
    """(line index, section, key) of every setting in DEFAULT_TOML."""
    out, section = [], ""
    for i, line in enumerate(DEFAULT_TOML.splitlines()):
        if line.startswith("["):
            section = line.split("]")[0].strip("[")
        elif (m := KEY_LINE.match(line)) and not section.startswith("trilat.anchors"):
            out.append((i, section, m["key"]))
    return out


def mutated(index: int, value: str) -> str:
    lines = DEFAULT_TOML.splitlines()
    m = KEY_LINE.match(lines[index])
    lines[index] = f"{m['key']} = {value}"
    return "\n".join(lines) + "\n"


def sane(obj: object, where: str = "") -> list[str]:
    """Problems an accepted config must not have, checked without the schema's ranges: every
    number finite (but the two timeouts that may be inf) and every time and period positive."""
    problems = []
    for f in fields(obj):
        value = getattr(obj, f.name)
        name = f"{where}.{f.name}"
        if is_dataclass(value):
            problems += sane(value, name)
            continue
        numbers = value if isinstance(value, (list, tuple)) else [value]
        for v in numbers:
            if isinstance(v, float) and not math.isfinite(v) and f.name not in ("odometry_wall_timeout_s", "max_time_s"):
                problems.append(f"{name} = {v}")
            if isinstance(v, (int, float)) and abs(v) > 1e6 and f.name not in ("seed", "odometry_wall_timeout_s",
                                                                              "max_time_s"):
                problems.append(f"{name} = {v}")
        if f.name.endswith(("_s", "_period_s", "_timeout_ms")) and f.name != "disambiguation_s" \
                and isinstance(value, (int, float)) and value < 0:
            problems.append(f"{name} = {value} < 0")
    return problems


def test_every_default_passes_its_own_range(tmp_path: Path) -> None:
    assert [p for name, cls in SECTIONS.items() for p in defaults_problems(cls, name)] == []
    path = tmp_path / "robot.toml"
    path.write_text(DEFAULT_TOML)
    assert load(path) == Config() and sane(Config()) == []


def test_every_key_of_the_default_file_is_checked() -> None:
    """Each setting line, given a string where a number goes (or a number where a string or a
    list goes), is refused: no key escapes the schema."""
    for index, section, key in key_lines():
        value = "[]" if KEY_LINE.match(DEFAULT_TOML.splitlines()[index])["value"].startswith(('"', "true", "false")) \
            else '"x"'
        with pytest.raises(ConfigError, match=re.escape(f"[{section}] {key} = ")):
            load_text(mutated(index, value))


BAD_CONFIGS = [
    ('[mounting]\nazimuth_sign = "x"\n', '[mounting] azimuth_sign = "x": expected a whole number of -1 or 1'),
    ("[calibration]\np0_dbm = nan\n", "[calibration] p0_dbm = nan: expected a number from -150 to 30 dBm"),
    ("[loop]\ncontrol_period_s = -5\n", "[loop] control_period_s = -5: expected a number above 0 and at most 10 s"),
    ('[loop]\nstale_timeout_s = "x"\n', '[loop] stale_timeout_s = "x": expected a number above 0'),
    ("[s2]\ndish_offsets_db = 5\n", "[s2] dish_offsets_db = 5: expected a list of 4 numbers"),
    ("[s2]\ndish_offsets_db = [0, 0, inf, 0]\n", "[s2] dish_offsets_db[2] = inf: expected a number from -40 to 40 dB"),
    ("[trilat.anchors]\nCCF9578E0D01 = [1, nan]\n", "[trilat] anchors.CCF9578E0D01[1] = nan"),
    ("[plan.grid]\nresolution = 0.01\nsize_m = 1000\n", "[plan.grid] size_m / resolution = 100000 cells"),
    ("[s1]\nenter_dbm = -80\n", "[s1] leave_dbm = -76.0 must be below enter_dbm = -80.0"),
    ('[s2]\nmotion = "fast"\n', '[s2] motion = "fast": expected one of "full", "preliminary"'),
    ("[loop]\ncommand_timeout_ms = 1e3\n", "[loop] command_timeout_ms = 1000.0: expected a whole number"),
    ("[loop\n", "is not valid TOML"),
    ("devices = 3\n", "devices must be tables"),
    # a list of numbers in a device setting was a TypeError (found by bench/fuzz.py's config target)
    ('[devices.aoa]\nport = "xplr-aoa:/dev/ttyUSB0"\nbaud = [1, 2]\n', "[devices.aoa]: bad baud='1+2'"),
]


def load_text(text: str | bytes, path: Path | None = None) -> Config:
    """``text`` loaded as a config file (in a scratch folder unless ``path`` is given)."""
    path = path or Path(_scratch()) / "robot.toml"
    path.write_bytes(text.encode() if isinstance(text, str) else text)
    return load(path)


_SCRATCH: list[str] = []


def _scratch() -> str:
    """One scratch folder for the generated files (hypothesis examples share it)."""
    if not _SCRATCH:
        import tempfile

        _SCRATCH.append(tempfile.mkdtemp(prefix="rfhoming-config-"))
    return _SCRATCH[0]


@pytest.mark.parametrize("text,message", BAD_CONFIGS)
def test_bad_values_are_refused_naming_key_range_and_unit(text: str, message: str) -> None:
    with pytest.raises(ConfigError, match=re.escape(message)):
        load_text(text)


def test_a_file_that_is_not_utf8_is_refused(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match=r"robot.toml is not UTF-8 text \(line 2, byte 12 is 0xff\): save it as UTF-8"):
        load_text(b'[loop]\nx = "\xff\xfe"\n', tmp_path / "robot.toml")


@pytest.mark.slow
def test_config_check_gives_one_line_and_exit_2(tmp_path: Path) -> None:
    for n, (text, message) in enumerate([*BAD_CONFIGS[:5], (b"\xff\xfe[loop]\n", "is not UTF-8 text")]):
        path = tmp_path / f"c{n}.toml"
        path.write_bytes(text.encode() if isinstance(text, str) else text)
        done = subprocess.run([*RFHOMING, "config", "--check", str(path)], capture_output=True, text=True, timeout=60)
        assert done.returncode == 2, (text, done.stdout)
        assert done.stderr.count("\n") == 1 and message in done.stderr and str(path) in done.stderr


@given(st.sampled_from(key_lines()), st.sampled_from(NASTY))
def test_a_mutated_config_is_accepted_sane_or_refused(line: tuple[int, str, str], value: str) -> None:
    index, section, key = line
    try:
        config = load_text(mutated(index, value))
    except ConfigError as exc:
        assert f"[{section}" in str(exc) and "\n" not in str(exc)
        return
    assert sane(config) == [], (section, key, value)


@given(st.binary(max_size=40), st.integers(0, len(DEFAULT_TOML.encode())))
def test_random_bytes_spliced_into_the_default_file_never_crash(junk: bytes, at: int) -> None:
    data = DEFAULT_TOML.encode()
    try:
        config = load_text(data[:at] + junk + data[at + len(junk) // 2:])
    except ConfigError as exc:
        assert "\n" not in str(exc)
        return
    assert sane(config) == []


def census() -> tuple[int, int]:
    """(accepted, all) over every setting line x every NASTY value: the figure in docs/testing.md."""
    accepted = 0
    for index, _, _ in key_lines():
        for value in NASTY:
            try:
                load_text(mutated(index, value))
                accepted += 1
            except ConfigError:
                pass
    return accepted, len(key_lines()) * len(NASTY)


# -- site files -----------------------------------------------------------------------------
SITE = (ROOT / "docs" / "sites" / "kit-room.toml").read_text()
NUMBER = re.compile(r"(?<![\w.\"])-?\d+(?:\.\d+)?(?![\w.\"])")


@given(st.data())
def test_a_mutated_site_is_accepted_sane_or_refused(data: st.DataObject) -> None:
    spots = list(NUMBER.finditer(SITE))
    spot = data.draw(st.sampled_from(spots))
    value = data.draw(st.sampled_from(["nan", "inf", "-inf", "1e300", '"x"', "[]", "true", "0", "-1e4", "1e4"]))
    path = Path(_scratch()) / "site.toml"
    path.write_text(SITE[:spot.start()] + value + SITE[spot.end():])
    try:
        site = sites.load(path)
    except sites.SiteError as exc:
        assert "\n" not in str(exc)
        return
    for a in site.anchors:
        assert all(math.isfinite(v) and abs(v) <= sites.MAX_COORD_M for v in a.position), a


@pytest.mark.parametrize("position,message", [
    ("[nan, 0, 2]", "needs position = [x, y, z] in metres, each a finite number"),
    ("[inf, 0, 2]", "needs position = [x, y, z] in metres, each a finite number"),
    ("[1e300, 0, 2]", "within +-10000 m"),
])
def test_site_positions_must_be_finite_and_near(tmp_path: Path, position: str, message: str) -> None:
    path = tmp_path / "site.toml"
    path.write_text(SITE.replace("position = [6.0, 6.0, 2.2]", f"position = {position}", 1))
    assert path.read_text() != SITE
    with pytest.raises(sites.SiteError, match=re.escape(message)):
        sites.load(path)


def test_anchors_at_one_point_are_refused(tmp_path: Path) -> None:
    text = re.sub(r"position = \[[^\]]*\]", "position = [1.0, 1.0, 2.0]", SITE)
    path = tmp_path / "site.toml"
    path.write_text(text)
    with pytest.raises(sites.SiteError, match="are 0.000 m apart; rays from one point cannot cross"):
        sites.load(path)


def test_every_site_and_points_file_in_docs_loads() -> None:
    for path in sorted((ROOT / "docs" / "sites").glob("*.toml")):
        if "points" not in path.name:
            assert len(sites.load(path).anchors) >= 2, path


def test_every_error_named_here_is_the_project_error() -> None:
    assert issubclass(ConfigError, Error) and issubclass(sites.SiteError, Error)
