"""Type checkers see the public API's real types, and the tree passes ruff.

mypy runs as a user's would: on a program in a folder outside the checkout, resolving
``rfhoming`` through ``sys.path`` (the installation these tests import), so the package's own
modules count as installed and only the program and the modules named with ``-m`` are checked.
"""

from __future__ import annotations

import ast
import os
import subprocess
import sys
from pathlib import Path

import pytest

import rfhoming
from test_docs import blocks

ROOT = Path(__file__).resolve().parent.parent
PACKAGE_PARENT = Path(rfhoming.__file__).resolve().parent.parent
TYPED_DOCS = [ROOT / "docs" / "api.md"]


PROGRAMS_CACHE = ROOT / ".mypy_cache" / "programs" / os.environ.get("PYTEST_XDIST_WORKER", "main")
"""mypy's incremental cache for the users' programs, shared by every run of :func:`mypy` in one
test process: the rfhoming modules a program imports are analysed once (10-20 s) instead of on
every run, as a user's repeated ``mypy`` runs share their ``.mypy_cache``. mypy checks each cached
module against its source, so a changed module is analysed again; the programs themselves always
are. One folder per xdist worker: mypy's cache is an SQLite file that two runs at once could lock."""


def mypy(cwd: Path, *args: str) -> subprocess.CompletedProcess[str]:
    """``mypy --strict ARGS`` in ``cwd``, seeing the rfhoming these tests import."""
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(PACKAGE_PARENT), *filter(None, [os.environ.get("PYTHONPATH")])])}
    return subprocess.run([sys.executable, "-m", "mypy", "--strict", "--no-color-output", "--cache-dir",
                           str(PROGRAMS_CACHE), *args], cwd=cwd, env=env, text=True, capture_output=True, timeout=600)


def test_the_names_type_checkers_see_are_the_ones_loaded_lazily() -> None:
    """The ``if TYPE_CHECKING:`` imports of rfhoming/__init__.py and its ``_API`` table agree."""
    tree = ast.parse((ROOT / "rfhoming" / "__init__.py").read_text())
    block = next(node for node in tree.body if isinstance(node, ast.If) and ast.unparse(node.test) == "TYPE_CHECKING")
    seen: dict[str, str] = {}
    for node in block.body:
        if isinstance(node, ast.ImportFrom):
            for alias in node.names:
                seen[alias.asname or alias.name] = f"{node.module}:{alias.name}"
        elif isinstance(node, ast.Assign):  # parse_spec = _parse
            seen[node.targets[0].id] = seen.pop(node.value.id)
    lazy = {name: where if ":" in where else f"{where}:{name}" for name, where in rfhoming._API.items()}
    assert seen == lazy


def test_importing_rfhoming_stays_light() -> None:
    """The TYPE_CHECKING imports must not run: ``import rfhoming.protocol`` loads no host code."""
    code = "import sys, rfhoming.protocol; print(sorted(m for m in sys.modules if m.startswith('rfhoming.host') or m == 'rfhoming.api'))"
    done = subprocess.run([sys.executable, "-c", code], text=True, capture_output=True, timeout=60, check=True)
    assert done.stdout.strip() == "[]"


@pytest.mark.slow
def test_the_whole_package_and_a_match_over_item_kinds_pass_mypy_strict() -> None:
    """Every module of the package, as the checkout holds it (pyproject.toml's [tool.mypy] sections
    name the untyped third-party modules), and tests/typed/item_kinds.py: ``match item.kind``
    narrows an item. One run, in the checkout, so mypy's cache there makes the next one quick."""
    env = {**os.environ, "MYPYPATH": os.pathsep.join([str(ROOT / "src"), str(ROOT / "tests" / "typed")])}
    done = subprocess.run([sys.executable, "-m", "mypy", "--strict", "--no-color-output", "--config-file",
                           "pyproject.toml", "-p", "rfhoming", "-m", "item_kinds"],
                          cwd=ROOT, env=env, text=True, capture_output=True, timeout=600)
    assert done.returncode == 0, f"mypy --strict -p rfhoming tests/typed/item_kinds.py:\n{done.stdout[-6000:]}{done.stderr}"
    assert "item_kinds.py" not in done.stdout


@pytest.mark.slow
@pytest.mark.parametrize("doc", TYPED_DOCS, ids=[str(d.relative_to(ROOT)) for d in TYPED_DOCS])
def test_the_docs_examples_pass_mypy_strict(doc: Path, tmp_path: Path) -> None:
    """Every ```python block of the page (those not run too), as one program like the docs test runs."""
    (tmp_path / "examples.py").write_text("\n".join(body for lang, _, body, _ in blocks(doc) if lang == "python"))
    done = mypy(tmp_path, "examples.py")
    assert done.returncode == 0, f"mypy --strict on {doc.name}'s examples:\n{done.stdout}{done.stderr}"


def test_mypy_strict_catches_typos_in_a_users_program(tmp_path: Path) -> None:
    """The check can fail: a misspelt field, a misspelt API name, an unnarrowed item."""
    (tmp_path / "typos.py").write_text(
        "import rfhoming\n"
        "for got in rfhoming.read('capture:run.pcapng', kinds={'angle'}):\n"
        "    print(got.item.azimuht)\n"
        "devices = rfhoming.opne('capture:run.pcapng')\n"
        "for other in rfhoming.read('capture:run.pcapng'):\n"
        "    print(other.item.x_mm)\n"
    )
    done = mypy(tmp_path, "typos.py")
    assert done.returncode == 1, done.stdout + done.stderr
    for line, what in ((3, '"AngleEvent" has no attribute "azimuht"'), (4, 'has no attribute "opne"'),
                       (6, 'has no attribute "x_mm"')):
        assert f"typos.py:{line}: error:" in done.stdout and what in done.stdout, done.stdout


def test_mypy_strict_catches_a_misspelt_kind(tmp_path: Path) -> None:
    """``kinds={"angel"}`` would yield nothing at all: the type checker names it, as does the call."""
    (tmp_path / "kind.py").write_text(
        "import rfhoming\n"
        "for got in rfhoming.read('capture:run.pcapng', kinds={'angle', 'odometry'}):\n"
        "    print(got.kind)\n"
        "devices = rfhoming.open('capture:run.pcapng', kinds={'angel'})\n"
        "reader = rfhoming.Reader(open('run.bin', 'rb'), kinds=['antenna_sett'])\n"
    )
    done = mypy(tmp_path, "kind.py")
    assert done.returncode == 1, done.stdout + done.stderr
    errors = [line for line in done.stdout.splitlines() if ": error:" in line]
    assert {line.split(":")[1] for line in errors} == {"4", "5"}, done.stdout


def test_ruff_passes() -> None:
    """The rules chosen in pyproject.toml ([tool.ruff]), over the whole tree."""
    done = subprocess.run([sys.executable, "-m", "ruff", "check", "--no-cache", "."], cwd=ROOT, text=True,
                          capture_output=True, timeout=300)
    assert done.returncode == 0, f"ruff check:\n{done.stdout[-4000:]}{done.stderr[-2000:]}"


def test_received_to_dict_takes_items_without_a_to_dict_method() -> None:
    """ESP-AT's and HCI's items have no ``to_dict()``; ``Received.to_dict`` used to call it."""
    from rfhoming.api import Received
    from rfhoming.protocol.espat import ScanReport

    got = Received(1.5, "esp", ScanReport("C0FFEE000001", -61, b"\x02\x01\x06", b"", 0))
    assert got.to_dict() == {"device": "esp", "t": 1.5, "kind": "scan_report", "address": "C0FFEE000001",
                             "rssi_dbm": -61, "adv_data": "020106", "scan_rsp": "", "addr_type": 0}


def test_every_item_kind_is_a_typed_class_attribute_that_pickles_as_before() -> None:
    """Each item type's ``kind`` is annotated ``ClassVar[Literal[...]]`` (what lets ``match item.kind``
    narrow), yet stays what it was: a plain string on the class and its items, not a field, and an
    item pickles back to its own type and is as ``to_dict`` had it."""
    import pickle
    from typing import ClassVar, ForwardRef, Literal, get_args, get_origin, get_type_hints

    from rfhoming import api
    from rfhoming.host.drivers import hci

    types = [getattr(hci, t.__forward_arg__) if isinstance(t, ForwardRef) else t for t in get_args(api.Item)]
    assert {t.kind for t in types} == set(api.KINDS)
    for cls in types:
        hint = get_type_hints(cls)["kind"]
        assert get_origin(hint) is ClassVar and get_args(hint) == (Literal[cls.kind],), (cls, hint)
        assert isinstance(cls.__dict__.get("kind"), str) and "kind" not in cls._fields, cls
        item = cls._make(range(len(cls._fields)))
        again = pickle.loads(pickle.dumps(item))
        assert type(again) is cls and again == item and again.kind == cls.kind
        if hasattr(cls, "to_dict"):
            assert next(iter(item.to_dict().items())) == ("kind", cls.kind)
