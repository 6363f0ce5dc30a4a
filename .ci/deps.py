"""The test environment against its lock, and the lock against known vulnerabilities: what .ci/run prints.

    python .ci/deps.py diff requirements/test.lock
        one line: the installed packages whose versions differ from the lock ("pytest 9.3.0 (lock 9.2.0)")
    python .ci/deps.py audit requirements/test.lock REPORT.json [ERRORS.txt]
        pip-audit's JSON report of the lock, read into one verdict line a service; exit 1 on a vulnerability
        with a fixed version, 0 when the service could not be reached (said so, never silently)
    python .ci/deps.py advisories requirements/test.lock
        the lock against requirements/advisories.toml, the advisories shipped with the project (offline)

Run with the interpreter of the environment in question (``diff`` reads its installed distributions).
docs/testing.md, "Reproducible installs" and "Supply chain", says why each verdict fails CI or only reports.
"""

from __future__ import annotations

import json
import sys
import tomllib
from importlib import metadata
from pathlib import Path
from typing import Any

from packaging.specifiers import SpecifierSet
from packaging.utils import canonicalize_name
from packaging.version import Version

ADVISORIES = Path(__file__).resolve().parent.parent / "requirements" / "advisories.toml"
NOT_OURS = {"pip", "rfhoming"}
"""Installed but never in the lock: the environment's own installer, and the project itself (editable)."""


def read_lock(path: Path) -> dict[str, Version]:
    """``name==version`` lines of a pip-compile output (comments, ``# via`` and options skipped)."""
    pins: dict[str, Version] = {}
    for raw in path.read_text().splitlines():
        line = raw.split("#", 1)[0].strip()
        if not line or line.startswith("-"):
            continue
        name, sep, version = line.partition("==")
        if not sep:
            raise ValueError(f"{path}: {raw!r} is not pinned with == (regenerate it with .ci/lock)")
        pins[canonicalize_name(name.split("[", 1)[0].strip())] = Version(version.split(";", 1)[0].strip())
    return pins


def installed() -> dict[str, Version]:
    """Every distribution an installer put in the running interpreter's environment, but pip and
    rfhoming. Metadata a wheel carries inside it for its own modules (ROS 2's wheels ship
    ``rclpy-7.1.5.egg-info`` beside ``ros_rclpy-7.1.6.dist-info``) has no INSTALLER: not a package
    of the index, and never in a lock."""
    found = {canonicalize_name(d.metadata["Name"]): Version(d.version) for d in metadata.distributions()
             if d.read_text("INSTALLER") is not None}
    return {name: version for name, version in found.items() if name not in NOT_OURS}


def differences(lock: dict[str, Version], have: dict[str, Version]) -> list[str]:
    """Each installed package that the lock pins at another version, or does not pin, by name."""
    return [f"{name} {version} (lock {lock[name]})" if name in lock else f"{name} {version} (not in the lock)"
            for name, version in sorted(have.items()) if lock.get(name) != version]


def audit_verdict(lock: dict[str, Version], report: dict[str, Any] | None, errors: str) -> tuple[int, list[str]]:
    """(exit code, lines) from pip-audit's JSON report, or from its stderr when it wrote none."""
    if report is None:
        reason = next((line for line in reversed(errors.splitlines()) if line.strip()), "no report written")
        return 0, [f"NOT RUN: the vulnerability service could not be reached ({reason.strip()[:300]})"]
    deps = report.get("dependencies", [])
    skipped = [d for d in deps if d.get("skip_reason")]
    audited = len(deps) - len(skipped)
    if audited == 0:
        reason = skipped[0]["skip_reason"] if skipped else "the report lists no package"
        return 0, [f"NOT RUN: the service answered for none of the {len(lock)} locked packages ({reason})"]
    found = [(d, v) for d in deps for v in d.get("vulns", [])]
    lines = [f"{d['name']} {d['version']}: {v['id']} ({', '.join(v.get('aliases', [])) or 'no alias'}), "
             f"fixed in {', '.join(v.get('fix_versions', [])) or 'no release yet'}" for d, v in found]
    fixable = [v for _, v in found if v.get("fix_versions")]
    head = (f"{audited} of {len(lock)} locked packages audited, {len(skipped)} skipped, "
            f"{len(found)} known vulnerabilities ({len(fixable)} with a fixed release)")
    return (1 if fixable else 0), [head, *lines]


def affected(version: Version, ranges: list[str]) -> bool:
    return any(SpecifierSet(r, prereleases=True).contains(version, prereleases=True) for r in ranges)


def shipped_advisories(lock: dict[str, Version]) -> tuple[int, list[str]]:
    """The lock's pins that requirements/advisories.toml knows to be affected."""
    entries = tomllib.loads(ADVISORIES.read_text())["advisory"]
    hits = [f"{e['package']} {lock[canonicalize_name(e['package'])]}: {e['id']} ({e['summary']})" for e in entries
            if canonicalize_name(e["package"]) in lock and affected(lock[canonicalize_name(e["package"])], e["affected"])]
    head = f"{len(entries)} shipped advisories ({ADVISORIES.name}) against {len(lock)} locked packages: {len(hits)} affected"
    return (1 if hits else 0), [head, *hits]


def main(argv: list[str]) -> int:
    command, lock_path, *rest = argv
    lock = read_lock(Path(lock_path))
    if command == "diff":
        diff = differences(lock, installed())
        print(", ".join(diff) if diff else f"every installed package as in {lock_path}")
        return 0
    if command == "audit":
        report_path = Path(rest[0])
        errors = Path(rest[1]).read_text() if len(rest) > 1 and Path(rest[1]).exists() else ""
        try:
            report = json.loads(report_path.read_text())
        except (OSError, ValueError):
            report = None
        code, lines = audit_verdict(lock, report, errors)
    elif command == "advisories":
        code, lines = shipped_advisories(lock)
    else:
        raise SystemExit(f"unknown command {command!r}: diff, audit or advisories")
    print("\n".join(lines))
    return code


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
