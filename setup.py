"""Builds the optional C accelerator; everything else is declared in pyproject.toml.

The import package ``rfhoming`` is the folder ``rfhoming/``; its layers are relative directory
symlinks committed in git (``rfhoming/protocol -> ../protocol``, ``rfhoming/firmware ->
../firmware_py``, ...), so every import name is a path that static tools (mypy, pyright, jedi,
import-linter) follow without running code. ``src/`` holds one more symlink, ``src/rfhoming ->
../rfhoming``: with ``package_dir = {"": "src"}`` an editable install is a plain path entry for
``src/``, where nothing but ``rfhoming`` is importable (docs/architecture.md).

Packages are found as namespace packages: the data folders (``emulator/scenarios``, the ROS 2 message
package ``host/export/rfhoming_msgs``) are imported by name (``resources.files("rfhoming.emulator.scenarios")``),
so they are packages of their own, listed with their data, not files smuggled in under their parents.

The extension is ``optional=True``: where no C compiler is found the build goes on without it and
the pure-Python decoders run (``python -m rfhoming.protocol.accel`` says which one is in use).
"""

import runpy
from pathlib import Path

from setuptools import Extension, find_namespace_packages, setup

# src/rfhoming/ is the link in a checkout and the copied folder in an sdist; in a checkout made
# without links it is a plain file, and rfhoming/_links.py is the one there to say so.
LINKS = [p for p in (Path(__file__).parent / d / "_links.py" for d in ("src/rfhoming", "rfhoming")) if p.is_file()][0]
try:  # a checkout without symlinks would build an empty wheel: say what to set instead
    runpy.run_path(str(LINKS))["check"]()
except ImportError as exc:
    raise SystemExit(f"error: {exc}") from None

setup(
    package_dir={"": "src"},
    packages=find_namespace_packages("src", include=["rfhoming*"], exclude=["*.__pycache__"]),
    ext_modules=[
        Extension("rfhoming.protocol._accel", ["src/rfhoming/protocol/_accel.c"], optional=True, extra_compile_args=["-O2"]),
    ],
)
