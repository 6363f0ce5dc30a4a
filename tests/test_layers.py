"""The layering of docs/architecture.md holds: import-linter's contracts (pyproject.toml) pass.

import-linter finds modules by walking the package's folder. An editable install maps
``rfhoming.protocol`` etc. to the repository's top-level folders, which that walk cannot see,
so the test lays the installed package out as a wheel would (file symlinks in a scratch folder)
and lints that: the same check for an editable install and for a wheel.
"""

from __future__ import annotations

import importlib
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
LAYERS = ("protocol", "firmware", "emulator", "host", "campaigns")


def stage(into: Path) -> Path:
    package = into / "rfhoming"
    top = Path(importlib.import_module("rfhoming").__file__).parent
    places = {package: top, **{package / name: Path(importlib.import_module(f"rfhoming.{name}").__path__[0])
                               for name in LAYERS}}
    for target, source in places.items():
        for path in source.rglob("*.py"):
            relative = path.relative_to(source)
            if target == package and relative.parts[0] in LAYERS:
                continue  # a wheel's own copy of a layer: staged from its import location
            (target / relative).parent.mkdir(parents=True, exist_ok=True)
            (target / relative).symlink_to(path)
    return into


def lint(staged: Path, config: Path) -> subprocess.CompletedProcess:
    lint_imports = shutil.which("lint-imports")
    assert lint_imports, "import-linter is part of the test extra: pip install -e '.[test]'"
    return subprocess.run([lint_imports, "--config", str(config), "--no-cache"], cwd=staged, text=True,
                          capture_output=True, env={**os.environ, "PYTHONPATH": str(staged)}, timeout=120)


def test_import_contracts_hold(tmp_path: Path) -> None:
    done = lint(stage(tmp_path), ROOT / "pyproject.toml")
    assert done.returncode == 0, done.stdout + done.stderr
    assert "Contracts: 5 kept, 0 broken" in done.stdout


def test_a_wrong_arrow_breaks_a_contract(tmp_path: Path) -> None:
    """The check can fail: host importing the emulator is caught."""
    staged = stage(tmp_path)
    bad = staged / "rfhoming" / "host" / "wrong_arrow.py"
    bad.write_text("from rfhoming.emulator import scenario\n")
    done = lint(staged, ROOT / "pyproject.toml")
    assert done.returncode != 0 and "rfhoming.host.wrong_arrow -> rfhoming.emulator" in done.stdout


@pytest.mark.parametrize("name", LAYERS)
def test_layers_install_inside_rfhoming_only(name: str) -> None:
    """Only ``rfhoming`` is importable at top level: no ``protocol``, ``host`` ... beside it."""
    done = subprocess.run([sys.executable, "-c", f"import {'firmware_py' if name == 'firmware' else name}"],
                          cwd="/", capture_output=True, text=True)
    assert done.returncode != 0 and "ModuleNotFoundError" in done.stderr


def test_tests_import_their_helpers_by_module_name() -> None:
    """``from tests.x import`` works only from the checkout's root; the suite must also run
    against an installed wheel from anywhere (issue 12), where pytest puts tests/ on the path."""
    offenders = [p.name for p in (ROOT / "tests").glob("*.py")
                 if any(line.startswith(("from tests.", "import tests")) for line in p.read_text().splitlines())]
    assert not offenders, offenders
