"""Builds the optional C accelerator; everything else is declared in pyproject.toml.

``optional=True``: where no C compiler is found the build goes on without it and the
pure-Python decoders run (``python -m protocol.accel`` says which one is in use).
"""

from setuptools import Extension, setup

setup(
    ext_modules=[
        Extension("protocol._accel", ["protocol/_accel.c"], optional=True, extra_compile_args=["-O2"]),
    ]
)
