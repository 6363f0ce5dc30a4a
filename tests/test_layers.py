"""The layering of docs/architecture.md holds: import-linter's contracts (pyproject.toml) pass.

Every import name is a path (``rfhoming/host -> ../host`` and the other layers are directory
symlinks in git), so ``lint-imports`` runs from the repository's root as a user would run it,
with nothing staged; the same walk serves mypy, pyright and jedi.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import sysconfig
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
LAYERS = ("protocol", "firmware", "emulator", "host", "campaigns")


def lint(cwd: Path) -> subprocess.CompletedProcess:
    # this interpreter's environment first: `venv/bin/python -m pytest` finds its own tools unactivated
    lint_imports = shutil.which("lint-imports", path=os.pathsep.join([sysconfig.get_path("scripts"), os.environ["PATH"]]))
    assert lint_imports, "import-linter is part of the test extra: pip install -e '.[test]'"
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    return subprocess.run([lint_imports, "--config", str(cwd / "pyproject.toml"), "--no-cache"], cwd=cwd, text=True,
                          capture_output=True, env={**env, "PYTHONPATH": str(cwd)}, timeout=120)


def test_import_contracts_hold_from_the_root() -> None:
    done = lint(ROOT)
    assert done.returncode == 0, done.stdout + done.stderr
    assert "Contracts: 6 kept, 0 broken" in done.stdout


def test_a_wrong_arrow_breaks_a_contract(tmp_path: Path) -> None:
    """The check can fail: host importing the emulator is caught (in a copy of the tree)."""
    shutil.copytree(ROOT / "rfhoming", tmp_path / "rfhoming", ignore=shutil.ignore_patterns("__pycache__", "*.so"))
    shutil.copy(ROOT / "pyproject.toml", tmp_path)
    (tmp_path / "rfhoming" / "host" / "wrong_arrow.py").write_text("from rfhoming.emulator import scenario\n")
    done = lint(tmp_path)
    assert done.returncode != 0 and "rfhoming.host.wrong_arrow -> rfhoming.emulator" in done.stdout


def test_a_command_importing_another_breaks_a_contract(tmp_path: Path) -> None:
    """Commands are thin apps over the library: one command module importing another is caught."""
    shutil.copytree(ROOT / "rfhoming", tmp_path / "rfhoming", ignore=shutil.ignore_patterns("__pycache__", "*.so"))
    shutil.copy(ROOT / "pyproject.toml", tmp_path)
    (tmp_path / "rfhoming" / "cli" / "commands" / "wrong_arrow.py").write_text("from rfhoming.cli.commands import decode\n")
    done = lint(tmp_path)
    assert done.returncode != 0 and "rfhoming.cli.commands.wrong_arrow -> rfhoming.cli.commands.decode" in done.stdout


@pytest.mark.parametrize("layer", LAYERS)
def test_each_layer_is_a_committed_directory_symlink(layer: str) -> None:
    """``rfhoming/LAYER`` is a relative link to the card's top-level folder, as git keeps it."""
    link = ROOT / "rfhoming" / layer
    assert link.is_symlink() and not os.path.isabs(os.readlink(link)), link
    folder = "firmware_py" if layer == "firmware" else layer
    assert link.resolve() == (ROOT / folder).resolve()
    mode = subprocess.run(["git", "ls-files", "-s", f"rfhoming/{layer}"], cwd=ROOT, capture_output=True,
                          text=True, timeout=60).stdout.split(" ")[0]
    assert mode in ("120000", ""), mode  # "" outside a git checkout (an sdist)


@pytest.mark.parametrize("name", LAYERS)
def test_layers_install_inside_rfhoming_only(name: str) -> None:
    """Only ``rfhoming`` is importable at top level: no ``protocol``, ``host`` ... beside it."""
    done = subprocess.run([sys.executable, "-c", f"import {'firmware_py' if name == 'firmware' else name}"],
                          cwd="/", capture_output=True, text=True, timeout=60)
    assert done.returncode != 0 and "ModuleNotFoundError" in done.stderr


def test_tests_import_their_helpers_by_module_name() -> None:
    """``from tests.x import`` works only from the checkout's root; the suite must also run
    against an installed wheel from anywhere (what users install is what is tested), where pytest puts tests/ on the path."""
    offenders = [p.name for p in (ROOT / "tests").glob("*.py")
                 if any(line.startswith(("from tests.", "import tests")) for line in p.read_text().splitlines())]
    assert not offenders, offenders
