"""A checkout made without symlinks (``core.symlinks=false``, Git for Windows' default) fails with one
line saying what to set, on import and on install, instead of importing nothing (docs/architecture.md)."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
GIT = ["git", "-c", "user.name=rfhoming tests", "-c", "user.email=tests@invalid", "-c", "init.defaultBranch=main"]


@pytest.fixture(scope="module")
def unlinked(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """This tree's package, setup.py and links, committed and cloned again as git writes them without symlinks."""
    if shutil.which("git") is None:
        pytest.skip("needs git, to check out links the way it does")
    repo = tmp_path_factory.mktemp("repo")
    shutil.copytree(ROOT / "rfhoming", repo / "rfhoming", symlinks=True, ignore=shutil.ignore_patterns("__pycache__"))
    shutil.copytree(ROOT / "src", repo / "src", symlinks=True)
    shutil.copy(ROOT / "setup.py", repo)
    subprocess.run([*GIT, "init", "-q"], cwd=repo, check=True, timeout=60)
    subprocess.run([*GIT, "add", "-A"], cwd=repo, check=True, timeout=60)
    subprocess.run([*GIT, "commit", "-qm", "tree"], cwd=repo, check=True, timeout=60)
    clone = tmp_path_factory.mktemp("clone") / "rfhoming-checkout"
    subprocess.run([*GIT, "clone", "-q", "-c", "core.symlinks=false", str(repo), str(clone)], check=True, timeout=60)
    return clone


def python(cwd: Path, *args: str) -> subprocess.CompletedProcess[str]:
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    return subprocess.run([sys.executable, *args], cwd=cwd, env=env, text=True, capture_output=True, timeout=120)


def test_git_writes_each_link_as_a_file_holding_its_target(unlinked: Path) -> None:
    """What the check looks for, as git itself does it (not as this test imagines it)."""
    assert (unlinked / "rfhoming" / "host").is_file() and (unlinked / "rfhoming" / "host").read_text() == "../host"
    assert (unlinked / "src" / "rfhoming").is_file()


@pytest.mark.parametrize("args", [("-c", "import rfhoming.host"), ("-m", "rfhoming", "--version")], ids=["import", "cli"])
def test_importing_from_such_a_checkout_says_what_to_set(unlinked: Path, args: tuple[str, ...]) -> None:
    done = python(unlinked, *args)
    last = done.stderr.strip().splitlines()[-1]
    assert done.returncode != 0 and last.startswith("ImportError: "), done.stderr
    assert "rfhoming/protocol is a plain file holding '../protocol'" in last and "core.symlinks=true" in last, last
    assert "git checkout -- rfhoming src" in last, last


def test_installing_from_such_a_checkout_says_what_to_set(unlinked: Path) -> None:
    """setup.py stops before building a wheel with nothing in it."""
    done = python(unlinked, "setup.py", "--name")
    assert done.returncode != 0, done.stdout
    lines = done.stderr.strip().splitlines()
    assert lines[-1].startswith("error: ") and "core.symlinks" in lines[-1], done.stderr


def test_a_checkout_with_its_links_passes_the_check() -> None:
    from rfhoming import _links

    assert _links.unlinked() is None and _links.unlinked(str(ROOT / "rfhoming")) is None
