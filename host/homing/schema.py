"""The homing config's schema helpers; they live in protocol/schema.py (the radio profile, which
the emulator reads too, shares them) and are re-exported here for the config's modules."""

from rfhoming.protocol.schema import (
    DB as DB,
    DBM as DBM,
    DEG as DEG,
    M as M,
    M_S as M_S,
    RAD_S as RAD_S,
    S as S,
    ConfigError as ConfigError,
    build as build,
    check as check,
    defaults_problems as defaults_problems,
    setting as setting,
)
