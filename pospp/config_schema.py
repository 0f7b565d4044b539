"""How a pipeline configuration key is typed and bounded (the machinery of :mod:`pospp.config`).

Every key of a config section is a dataclass field; :func:`key` attaches its :class:`Limits`
(the physical range of a number, the length of a string), :func:`convert_value` turns a parsed
TOML value into the field's type, and :func:`out_of_range` lists the keys of a section whose
values are outside their range (for a configuration built in Python, which bypasses the
loader). Errors are :class:`ConfigError` and name the file and the key, with what was expected
and what was found.

Every number must be finite and within a physical range: a range wider than physics lets
nonsense through to where it fails as something else (docs/decisions.md "Physical ranges for
every config number").
"""

from __future__ import annotations

import dataclasses
import math
import types
import typing
from dataclasses import dataclass, field
from enum import Enum
from typing import Any

__all__ = ["MAX_CONFIG_BYTES", "MAX_STRING_LEN", "ConfigError", "Limits", "convert_value",
           "key", "limits_of", "out_of_range"]


class ConfigError(ValueError):
    """A pipeline configuration problem (names the file and key)."""


MAX_CONFIG_BYTES = 1 << 20
"""Largest pipeline file read [bytes] (a real one is a few kB)."""
MAX_STRING_LEN = 256
"""Longest string value of any key (a key may set a smaller limit)."""


@dataclass(frozen=True)
class Limits:
    """Range of one key: bounds for numbers (each element of a list), lengths for strings.

    Every number must also be finite; every string at most ``MAX_STRING_LEN`` characters.
    """

    gt: float | None = None
    ge: float | None = None
    lt: float | None = None
    le: float | None = None
    min_len: int = 0
    max_len: int = MAX_STRING_LEN

    def describe(self) -> str:
        """The limits as text: "> 0, <= 1000"."""
        parts = [f"{op} {v:g}" for op, v in ((">", self.gt), (">=", self.ge), ("<", self.lt),
                                             ("<=", self.le)) if v is not None]
        return ", ".join(parts)

    def problem(self, value: Any, where: str) -> str | None:
        """What is wrong with ``value`` (text naming ``where``), None when it is in range."""
        if isinstance(value, str):
            if not self.min_len <= len(value) <= self.max_len:
                return (f"{where}: expected a string of {self.min_len} to {self.max_len} "
                        f"characters, got {len(value)}")
            return None
        if isinstance(value, bool) or not isinstance(value, int | float):
            return None
        if not math.isfinite(value):
            return f"{where}: expected a finite number, got {value!r}"
        bad = ((self.gt is not None and not value > self.gt)
               or (self.ge is not None and not value >= self.ge)
               or (self.lt is not None and not value < self.lt)
               or (self.le is not None and not value <= self.le))
        return f"{where}: expected a value {self.describe()}, got {value!r}" if bad else None

    def check(self, value: Any, where: str) -> None:
        """Raise :class:`ConfigError` naming ``where`` when ``value`` is out of range."""
        text = self.problem(value, where)
        if text is not None:
            raise ConfigError(text)


def key(default: Any, **limits: Any) -> Any:
    """A config field with its limits (kept next to the field, read by the validation)."""
    return field(default=default, metadata={"limits": Limits(**limits)})


def limits_of(cls: type, name: str) -> Limits:
    """The limits of key ``name`` of config section ``cls`` (defaults when it sets none)."""
    f = {f.name: f for f in dataclasses.fields(cls)}[name]
    return f.metadata.get("limits", Limits())


def _items(value: Any, where: str) -> list[tuple[Any, str]]:
    """(element, where) of a value: each element of a tuple (``where[i]``), else itself."""
    if isinstance(value, tuple):
        return [(v, f"{where}[{i}]") for i, v in enumerate(value)]
    return [(value, where)]


def check_value(cls: type, name: str, value: Any, where: str) -> None:
    """Every element of ``value`` within the limits of key ``name`` of ``cls`` (else
    :class:`ConfigError`); None passes (an optional key left out)."""
    limits = limits_of(cls, name)
    for item, at in _items(value, where):
        if item is not None:
            limits.check(item, at)


def out_of_range(section: Any, prefix: str) -> list[str]:
    """The keys of a config section instance whose values are outside their limits (one text
    each, naming ``prefix.key``): a configuration made in Python is not validated on the way
    in (``dataclasses.replace``), so the QC stage asks this of the one it ran with."""
    out = []
    for f in dataclasses.fields(section):
        limits = f.metadata.get("limits")
        if limits is None:
            continue
        for item, at in _items(getattr(section, f.name), f"{prefix}.{f.name}"):
            text = None if item is None else limits.problem(item, at)
            if text is not None:
                out.append(text)
    return out


def _short(value: Any, n: int = 60) -> str:
    text = repr(value)
    return text if len(text) <= n else f"{text[:n]}... ({len(text)} characters)"


def convert_value(value: Any, tp: Any, where: str) -> Any:
    """A parsed TOML ``value`` as the field type ``tp`` (numbers, bools, strings, enums,
    fixed-length tuples, optionals), else :class:`ConfigError` naming ``where``."""
    origin = typing.get_origin(tp)
    args = typing.get_args(tp)
    if origin in (typing.Union, types.UnionType):
        if value is None and type(None) in args:
            return None
        inner = [a for a in args if a is not type(None)]
        return convert_value(value, inner[0], where)
    if origin is tuple:
        if not isinstance(value, list | tuple) or len(value) != len(args):
            raise ConfigError(f"{where}: expected a list of {len(args)} numbers, "
                              f"got {_short(value)}")
        pairs = enumerate(zip(value, args, strict=True))
        return tuple(convert_value(v, a, f"{where}[{i}]") for i, (v, a) in pairs)
    if isinstance(tp, type) and issubclass(tp, Enum):
        members = [m.value for m in tp]
        if not isinstance(value, str) or value not in members:
            raise ConfigError(f"{where}: expected one of {members}, got {_short(value)}")
        return tp(value)
    if tp is bool:
        if not isinstance(value, bool):
            raise ConfigError(f"{where}: expected true or false, got {_short(value)}")
        return value
    if tp is float:
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise ConfigError(f"{where}: expected a number, got {_short(value)}")
        try:
            return float(value)
        except OverflowError:
            raise ConfigError(f"{where}: expected a finite number, "
                              f"got {_short(value)}") from None
    if tp is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ConfigError(f"{where}: expected an integer, got {_short(value)}")
        return value
    if tp is str:
        if not isinstance(value, str):
            raise ConfigError(f"{where}: expected a string, got {_short(value)}")
        return value
    raise ConfigError(f"{where}: unsupported type {tp!r}")


def short_repr(value: Any) -> str:
    """``repr(value)`` cut to 60 characters (for messages that quote a bad value)."""
    return _short(value)
