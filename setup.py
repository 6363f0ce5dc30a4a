"""Maps the repository's folders into the one import package ``rfhoming`` and builds the optional
C accelerator; everything else is declared in pyproject.toml.

Each top-level folder is installed as a sub-package (``protocol/`` -> ``rfhoming.protocol``,
``firmware_py/`` -> ``rfhoming.firmware``, ...; docs/architecture.md has the table), so after
``pip install`` only ``rfhoming`` is importable at top level.

The extension is ``optional=True``: where no C compiler is found the build goes on without it and
the pure-Python decoders run (``python -m rfhoming.protocol.accel`` says which one is in use).
"""

from setuptools import Extension, find_packages, setup

FOLDERS = {  # import name -> folder in the repository
    "rfhoming": "rfhoming",
    "rfhoming.protocol": "protocol",
    "rfhoming.firmware": "firmware_py",
    "rfhoming.emulator": "emulator",
    "rfhoming.host": "host",
    "rfhoming.campaigns": "campaigns",
}

package_dir = {}
for name, folder in FOLDERS.items():
    package_dir[name] = folder
    for sub in find_packages(folder):
        package_dir[f"{name}.{sub}"] = f"{folder}/{sub.replace('.', '/')}"

setup(
    package_dir=package_dir,
    packages=sorted(package_dir),
    ext_modules=[
        Extension("rfhoming.protocol._accel", ["protocol/_accel.c"], optional=True, extra_compile_args=["-O2"]),
    ],
)
