"""A TOML file's schema is its dataclasses: each field's type annotation plus the range and unit
that :func:`setting` attaches. :func:`build` walks them to turn a TOML table into a settings
object, so no key can be added without a check, and every refusal names the file, the table,
the key, what is allowed (with the unit) and the default. The homing config
(host/homing/config.py) and the radio profile (protocol/radio_profile.py) are read with it; it
sits in protocol/ so that both the host and the emulator can read a profile.
"""

from __future__ import annotations

import functools
import math
import types
from dataclasses import MISSING, Field, field, fields, is_dataclass
from typing import Any, Union, get_args, get_origin, get_type_hints

from rfhoming.protocol.errors import Error

S, M, DEG, DB, DBM, M_S, RAD_S = "s", "m", "degrees", "dB", "dBm", "m/s", "rad/s"
"""Units, as the messages name them."""


class ConfigError(Error, ValueError):
    """A config file that cannot be used; the message says which key and how to fix it."""


def setting(default: Any = MISSING, *, low: float = -math.inf, high: float = math.inf, unit: str = "",
            above: bool = False, inf: bool = False, choices: tuple[Any, ...] = (), length: int | None = None,
            factory: Any = None) -> Any:
    """A dataclass field with its range: ``low``..``high`` (``above``: strictly above ``low``),
    ``unit`` for the message, ``inf``: infinity is a meaningful value, ``choices`` for strings
    and ints, ``length`` for lists of numbers."""
    meta = {"low": low, "high": high, "unit": unit, "above": above, "inf": inf, "choices": choices, "length": length}
    if factory is not None:
        return field(default_factory=factory, metadata=meta)
    return field(default=default, metadata=meta)


@functools.cache
def _hints(cls: type) -> dict[str, Any]:
    """A settings class's resolved annotations, once: resolving them costs more than checking
    a whole table (a config load built nine every time)."""
    return get_type_hints(cls)


def build(cls: type, table: Any, where: str, source: Any) -> Any:
    """``cls`` from a TOML table: unknown keys, wrong types and out-of-range values raise
    :class:`ConfigError`; keys left out keep their defaults."""
    if not isinstance(table, dict):
        raise ConfigError(f"{source}: [{where}] must be a table of key = value lines, not {table!r}")
    known = {f.name: f for f in fields(cls)}
    unknown = sorted(set(table) - set(known))
    if unknown:
        raise ConfigError(f"{source}: [{where}] has unknown keys {unknown}; known: {sorted(known)}")
    hints = _hints(cls)
    return cls(**{name: check(hints[name], value, known[name], where, source) for name, value in table.items()})


def defaults_problems(cls: type, where: str) -> list[str]:
    """Each default of ``cls`` (and its nested settings) that its own range refuses."""
    problems = []
    hints = _hints(cls)
    for f in fields(cls):
        value = f.default_factory() if f.default_factory is not MISSING else f.default
        if is_dataclass(hints[f.name]):
            problems += defaults_problems(hints[f.name], f"{where}.{f.name}")
            continue
        if value is None and _optional(hints[f.name]) is not None:  # "not set" is its own default
            continue
        try:
            check(hints[f.name], _as_toml(value), f, where, "defaults")
        except ConfigError as exc:
            problems.append(str(exc))
    return problems


def _as_toml(value: Any) -> Any:
    if isinstance(value, tuple):
        return list(value)
    return value


def check(tp: Any, value: Any, f: Field[Any], where: str, source: Any, key: str = "") -> Any:
    """``value`` of the field ``f`` (type ``tp``) as the dataclass wants it, or ConfigError;
    ``key`` names an element of a list or table field in the message (default: the field)."""
    key = key or f.name
    if _optional(tp) is not None:  # TOML has no null: a key that is there gives the value
        tp = _optional(tp)
    if isinstance(tp, type) and is_dataclass(tp):
        return build(tp, value, f"{where}.{f.name}", source)
    meta = f.metadata
    origin = get_origin(tp)
    if origin in (tuple, list):
        args = [a for a in get_args(tp) if a is not Ellipsis]
        length = meta.get("length") or (len(args) if origin is tuple and Ellipsis not in get_args(tp) else None)
        if not isinstance(value, list) or (length is not None and len(value) != length):
            _refuse(value, f, where, source, key, f"a list of {length or 'any number of'} numbers")
        items = [_scalar(args[0] if len(args) == 1 or length is None else args[i], v, f, where, source,
                         f"{key}[{i}]") for i, v in enumerate(value)]
        return tuple(items) if origin is tuple else items
    if origin is dict:
        if not isinstance(value, dict):
            _refuse(value, f, where, source, key, f"a table of NAME = value lines under [{where}.{f.name}]")
        return {str(k): check(get_args(tp)[1], v, f, where, source, f"{key}.{k}") for k, v in value.items()}
    return _scalar(tp, value, f, where, source, key)


def _optional(tp: Any) -> Any:
    if get_origin(tp) in (Union, types.UnionType) and type(None) in get_args(tp):
        return next(a for a in get_args(tp) if a is not type(None))
    return None


def _scalar(tp: Any, value: Any, f: Field[Any], where: str, source: Any, key: str) -> Any:
    meta = f.metadata
    if tp is bool:
        if not isinstance(value, bool):
            _refuse(value, f, where, source, key, "true or false")
        return value
    if tp is str:
        if not isinstance(value, str) or (meta.get("choices") and value not in meta["choices"]):
            _refuse(value, f, where, source, key, "one of " + ", ".join(f'"{c}"' for c in meta.get("choices", ())))
        return value
    if tp is int:
        if isinstance(value, bool) or not isinstance(value, int) or not _in_range(value, meta):
            _refuse(value, f, where, source, key, "a whole number " + _range(meta))
        return value
    if tp is float:
        number = _as_float(value)
        ok = (number is not None and not math.isnan(number)
              and (math.isfinite(number) or meta.get("inf")) and _in_range(number, meta))
        if not ok:
            _refuse(value, f, where, source, key, "a number " + _range(meta))
        return number
    raise TypeError(f"the config schema has no check for {tp!r} ({where}.{f.name})")  # a bug, not the user's


def _as_float(value: Any) -> float | None:
    """A TOML number as a float; None for anything else, and for an integer past a float's range (400 digits)."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return None
    try:
        return float(value)
    except OverflowError:
        return None


def _in_range(value: float, meta: Any) -> bool:
    if meta.get("choices"):
        return value in meta["choices"]
    low: float
    high: float
    low, high = meta.get("low", -math.inf), meta.get("high", math.inf)
    return (value > low if meta.get("above") else value >= low) and value <= high


def _range(meta: Any) -> str:
    unit = f" {meta['unit']}" if meta.get("unit") else ""
    if meta.get("choices"):
        return "of " + " or ".join(str(c) for c in meta["choices"]) + unit
    low, high = meta.get("low", -math.inf), meta.get("high", math.inf)
    infinite = " (inf allowed)" if meta.get("inf") else ""
    if math.isinf(low) and math.isinf(high):
        return f"(finite){unit}"
    if math.isinf(high):
        return f"{'above' if meta.get('above') else 'at least'} {low:g}{unit}{infinite}"
    if math.isinf(low):
        return f"at most {high:g}{unit}"
    return f"{'above' if meta.get('above') else 'from'} {low:g} {'and at most' if meta.get('above') else 'to'} {high:g}{unit}"


def _refuse(value: Any, f: Field[Any], where: str, source: Any, key: str, expected: str) -> None:
    default = f.default_factory() if f.default_factory is not MISSING else f.default
    hint = "" if default is None or default is MISSING or isinstance(default, dict) or key != f.name else f"; the default is {_toml(default)}"
    raise ConfigError(f"{source}: [{where}] {key} = {_toml(value)}: expected {expected}{hint}")


def _toml(value: Any) -> str:
    """How the value reads in TOML (true, not True; "x" in double quotes), cut short."""
    if isinstance(value, bool):
        text = "true" if value else "false"
    elif isinstance(value, str):
        text = '"' + value.replace('"', '\\"') + '"'
    elif isinstance(value, (list, tuple)):
        text = "[" + ", ".join(_toml(v) for v in value) + "]"
    elif isinstance(value, dict):
        text = "{" + ", ".join(f"{k} = {_toml(v)}" for k, v in value.items()) + "}"
    else:
        text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."
