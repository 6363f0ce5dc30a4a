"""What a user's install gets: the lock covers the test extra, every floor lies past the published
security fixes, the package builds without setuptools' warnings and ships its data, and our own
deprecations fail the suite (docs/testing.md, "Reproducible installs" and "Supply chain")."""

from __future__ import annotations

import importlib.util
import re
import shutil
import subprocess
import sys
import tarfile
import tomllib
import warnings
import zipfile
from pathlib import Path
from types import ModuleType

import pytest
from packaging.requirements import Requirement
from packaging.specifiers import SpecifierSet
from packaging.utils import canonicalize_name
from packaging.version import Version

ROOT = Path(__file__).resolve().parent.parent
LOCK = ROOT / "requirements" / "test.lock"
PYPROJECT = tomllib.loads((ROOT / "pyproject.toml").read_text())


def ci_deps() -> ModuleType:
    """.ci/deps.py, the script .ci/run calls, as a module."""
    spec = importlib.util.spec_from_file_location("ci_deps", ROOT / ".ci" / "deps.py")
    assert spec and spec.loader
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def requirements(*groups: str) -> list[Requirement]:
    """pyproject.toml's requirements: ``dependencies``, the named extras and ``build`` (build-system)."""
    found = []
    for group in groups:
        if group == "dependencies":
            found += PYPROJECT["project"]["dependencies"]
        elif group == "build":
            found += PYPROJECT["build-system"]["requires"]
        else:
            found += PYPROJECT["project"]["optional-dependencies"][group]
    return [Requirement(r) for r in found]


def test_the_lock_pins_every_requirement_of_the_test_install_within_its_range() -> None:
    """A dependency added to pyproject.toml without re-running .ci/lock, or a range moved past the lock, fails here."""
    lock = ci_deps().read_lock(LOCK)
    for req in requirements("dependencies", "test"):
        if req.marker is not None and not req.marker.evaluate({"extra": "test"}):
            continue
        name = canonicalize_name(req.name)
        assert name in lock, f"{req.name} is not in {LOCK.name}: run .ci/lock"
        assert req.specifier.contains(lock[name], prereleases=True), \
            f"{LOCK.name} pins {req.name} {lock[name]}, outside pyproject.toml's {req}: run .ci/lock"


def upper_bound(affected: str) -> Version:
    """The first version past one affected range ("<4.66.3", ">=5.26.0rc1,<5.29.5")."""
    bounds = [Version(s.version) for s in SpecifierSet(affected) if s.operator == "<"]
    assert bounds, f"an affected range needs its upper bound: {affected}"
    return max(bounds)


def test_every_floor_lies_past_the_published_fixes() -> None:
    """No version pyproject.toml allows, in any extra or the build, is in an affected range of requirements/advisories.toml."""
    advisories = tomllib.loads((ROOT / "requirements" / "advisories.toml").read_text())["advisory"]
    groups = ["dependencies", "build", *PYPROJECT["project"]["optional-dependencies"]]
    checked = 0
    for req in requirements(*groups):
        for advisory in (a for a in advisories if canonicalize_name(a["package"]) == canonicalize_name(req.name)):
            floors = [Version(s.version) for s in req.specifier if s.operator == ">="]
            assert floors, f"{req} allows every version affected by {advisory['id']}: give it a floor"
            past = max(upper_bound(r) for r in advisory["affected"])
            assert max(floors) >= past, f"{req} allows versions affected by {advisory['id']}: raise it to >={past}"
            checked += 1
    assert checked >= 9  # tqdm, protobuf (3), setuptools (3, build and test), pytest, distributed (test and campaign)


def test_the_lock_has_no_pin_the_shipped_advisories_know_to_be_affected(tmp_path: Path) -> None:
    deps = ci_deps()
    assert deps.shipped_advisories(deps.read_lock(LOCK))[0] == 0
    old = tmp_path / "old.lock"
    old.write_text("tqdm==4.66.2\n    # via rfhoming\nprotobuf==6.31.1\nnumpy==2.4.6\n")
    code, lines = deps.shipped_advisories(deps.read_lock(old))
    assert code == 1 and lines[0].endswith("3 locked packages: 2 affected"), lines
    assert any(line.startswith("tqdm 4.66.2: GHSA-g7vv-2v7x-gj9p") for line in lines), lines
    assert any(line.startswith("protobuf 6.31.1: GHSA-7gcm-g887-7qv7") for line in lines), lines


def test_the_newest_stage_names_each_package_that_differs_from_the_lock() -> None:
    deps = ci_deps()
    lock = {"pytest": Version("9.2.0"), "numpy": Version("2.4.6"), "scipy": Version("1.17.1")}
    have = {"pytest": Version("9.3.0"), "numpy": Version("2.4.6"), "scipy": Version("1.17.1"), "pyee": Version("13.0.1")}
    assert deps.differences(lock, have) == ["pyee 13.0.1 (not in the lock)", "pytest 9.3.0 (lock 9.2.0)"]
    assert deps.differences(lock, dict(lock)) == []


def test_a_lock_line_without_a_pin_is_refused(tmp_path: Path) -> None:
    loose = tmp_path / "loose.lock"
    loose.write_text("numpy>=1.26\n")
    with pytest.raises(ValueError, match="not pinned with == .*\\.ci/lock"):
        ci_deps().read_lock(loose)


@pytest.mark.parametrize("report,errors,code,first", [
    (None, "Traceback ...\nrequests.exceptions.ConnectionError: Failed to resolve 'api.osv.dev'\n", 0,
     "NOT RUN: the vulnerability service could not be reached (requests.exceptions.ConnectionError: Failed to resolve 'api.osv.dev')"),
    ({"dependencies": [{"name": "numpy", "skip_reason": "Dependency not found on PyPI"}]}, "", 0,
     "NOT RUN: the service answered for none of the 2 locked packages (Dependency not found on PyPI)"),
    ({"dependencies": [{"name": "numpy", "version": "2.4.6", "vulns": []},
                       {"name": "tqdm", "version": "4.66.2", "vulns": [
                           {"id": "PYSEC-2024-x", "aliases": ["CVE-2024-34062"], "fix_versions": ["4.66.3"]}]}]}, "", 1,
     "2 of 2 locked packages audited, 0 skipped, 1 known vulnerabilities (1 with a fixed release)"),
    ({"dependencies": [{"name": "numpy", "version": "2.4.6", "vulns": [{"id": "GHSA-x", "fix_versions": []}]},
                       {"name": "tqdm", "version": "4.70.1", "vulns": []}]}, "", 0,
     "2 of 2 locked packages audited, 0 skipped, 1 known vulnerabilities (0 with a fixed release)"),
], ids=["unreachable", "nothing-answered", "fixable", "no-fix-yet"])
def test_the_audit_fails_on_a_fixable_vulnerability_and_says_when_it_could_not_run(
        report: dict | None, errors: str, code: int, first: str) -> None:
    lock = {"numpy": Version("2.4.6"), "tqdm": Version("4.66.2")}
    got_code, lines = ci_deps().audit_verdict(lock, report, errors)
    assert (got_code, lines[0]) == (code, first), lines
    if code:
        assert lines[1] == "tqdm 4.66.2: PYSEC-2024-x (CVE-2024-34062), fixed in 4.66.3"


def copy_tree(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The package's part of the checkout, links kept, as a clean clone holds it (the checkout stays as it is)."""
    tree = tmp_path_factory.mktemp("tree")
    for folder in ("rfhoming", "src", "protocol", "firmware_py", "emulator", "host", "campaigns"):
        shutil.copytree(ROOT / folder, tree / folder, symlinks=True,
                        ignore=shutil.ignore_patterns("__pycache__", "*.so", "*.egg-info"))
    for name in ("setup.py", "pyproject.toml", "README.md"):
        shutil.copy(ROOT / name, tree)
    return tree


@pytest.fixture(scope="module")
def built(tmp_path_factory: pytest.TempPathFactory) -> subprocess.CompletedProcess[str]:
    """setup.py's build_py on a copy of the tree: what a wheel would hold."""
    tree = copy_tree(tmp_path_factory)
    return subprocess.run([sys.executable, "setup.py", "build_py", "--build-lib", str(tree / "out")], cwd=tree,
                          text=True, capture_output=True, timeout=300)


def test_the_package_builds_without_setuptools_warnings_and_ships_its_data(built: subprocess.CompletedProcess[str]) -> None:
    """Data folders declared as packages, an SPDX license: nothing for setuptools to warn about (or to stop
    building), and the scenarios and the ROS 2 message package still in what a wheel holds."""
    assert built.returncode == 0, built.stderr[-3000:]
    assert not re.search(r"\w*Warning\b", built.stderr), built.stderr[-3000:]
    out = Path(built.args[-1])
    shipped = {p.relative_to(out / "rfhoming").as_posix() for p in out.rglob("*") if p.is_file()}
    scenarios = {f"emulator/scenarios/{p.name}" for p in (ROOT / "emulator" / "scenarios").glob("*.toml")}
    messages = {f"host/export/rfhoming_msgs/msg/{p.name}" for p in (ROOT / "host" / "export" / "rfhoming_msgs" / "msg").glob("*.msg")}
    assert len(scenarios) > 10 and len(messages) >= 4
    assert scenarios | messages | {"py.typed", "host/foxglove_layout.json", "host/export/rfhoming_msgs/package.xml",
                                   "host/export/rfhoming_msgs/CMakeLists.txt"} <= shipped


def test_a_deprecation_in_our_code_fails_and_a_librarys_own_stays_a_warning() -> None:
    """pyproject.toml's filterwarnings: warnings attributed to rfhoming.* or to tests/ modules are errors."""
    with pytest.raises(DeprecationWarning):
        warnings.warn("old API", DeprecationWarning, stacklevel=1)  # attributed to this test module
    with pytest.raises(DeprecationWarning):
        warnings.warn_explicit("old API", DeprecationWarning, "host/x.py", 1, module="rfhoming.host.x")
    with pytest.warns(DeprecationWarning):
        warnings.warn_explicit("old API", DeprecationWarning, "lib/core.py", 1, module="somelib.core")


def data_files() -> set[str]:
    """The package data a release must carry, as paths under ``rfhoming/``."""
    layers = {"emulator/scenarios": "*.toml", "protocol/profiles": "*.toml", "host/export/rfhoming_msgs/msg": "*.msg"}
    found = {f"{folder}/{p.name}" for folder, pattern in layers.items() for p in (ROOT / folder).glob(pattern)}
    return found | {"py.typed", "host/foxglove_layout.json", "host/export/rfhoming_msgs/package.xml",
                    "protocol/_accel.pyi"}


@pytest.mark.slow  # about 25 s: an sdist, then a wheel compiled from it
def test_the_sdist_holds_one_copy_of_the_package_and_builds_a_wheel(tmp_path_factory: pytest.TempPathFactory) -> None:
    """``python -m build`` as a packager runs it: the sdist first, then a wheel from the unpacked sdist, where no
    link is left (the route pip takes on a platform without a wheel). Each module once, under src/rfhoming/ (a
    link followed twice would ship it three times), the C source beside it, the data in both."""
    tree = copy_tree(tmp_path_factory)
    out = tree / "dist"
    done = subprocess.run([sys.executable, "-m", "build", "--no-isolation", "--outdir", str(out), str(tree)],
                          text=True, capture_output=True, timeout=600)
    assert done.returncode == 0, (done.stdout + done.stderr)[-3000:]
    [sdist], [wheel] = out.glob("*.tar.gz"), out.glob("*.whl")
    with tarfile.open(sdist) as archive:
        names = [n.split("/", 1)[1] for n in archive.getnames() if "/" in n]
    package = {n.removeprefix("src/rfhoming/") for n in names if n.startswith("src/rfhoming/")}
    outside = {n for n in names if not n.startswith(("src/", "tests/")) and "/" in n}
    assert outside == set(), f"the sdist holds files outside src/ and tests/: {sorted(outside)[:5]}"
    assert "protocol/_accel.c" in package and "_links.py" in package
    assert data_files() <= package, sorted(data_files() - package)
    modules = sorted(p.relative_to(ROOT / "host").as_posix() for p in (ROOT / "host").rglob("*.py")
                     if "__pycache__" not in p.parts)
    assert modules and all(f"host/{m}" in package for m in modules)
    with zipfile.ZipFile(wheel) as archive:
        shipped = {n.removeprefix("rfhoming/") for n in archive.namelist() if n.startswith("rfhoming/")}
    assert data_files() <= shipped, sorted(data_files() - shipped)
    assert not {n for n in shipped if n.endswith(".c")}, "the wheel ships the C source"
    assert {n for n in shipped if n.endswith(".py")} == {n for n in package if n.endswith(".py")}
