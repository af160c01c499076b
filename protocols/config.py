"""Configuration from mappings (TOML/JSON sections), for every config in the project.

One error type, :class:`ConfigError`, that names the file (when there is one), the key
(dotted: ``link.rate``) and the reason; an unknown key raises :class:`UnknownKeyError`,
which is also a ``TypeError`` (like an unknown keyword argument). One builder,
:func:`dataclass_from_mapping`, for frozen parameter dataclasses, and one 3-vector
validator, :func:`vec3`, and one check of numeric fields, :func:`check_numbers`. Pure.
"""

from __future__ import annotations

import dataclasses
import math
import numbers
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any, TypeVar

__all__ = [
    "ConfigError",
    "UnknownKeyError",
    "check_keys",
    "check_numbers",
    "dataclass_from_mapping",
    "vec3",
]

_T = TypeVar("_T")


class ConfigError(ValueError):
    """An unusable configuration: ``file`` (or None), ``key`` (dotted, or None), ``reason``.

    ``str()`` reads ``<file>: <key>: <reason>`` with the parts that are known.
    """

    def __init__(self, reason: str, *, key: str | None = None, file: str | Path | None = None):
        self.reason = reason
        self.key = key
        self.file = None if file is None else str(file)
        super().__init__(": ".join(p for p in (self.file, key, reason) if p))

    def in_file(self, file: str | Path) -> ConfigError:
        """The same error, naming ``file`` (for loaders that parse after reading)."""
        return type(self)(self.reason, key=self.key, file=file)


class UnknownKeyError(ConfigError, TypeError):
    """A mapping named a key that is not a field (the message lists the valid keys)."""


def _join(where: str, key: str) -> str:
    return f"{where}.{key}" if where else key


def check_keys(values: Any, allowed: set[str] | frozenset[str], where: str = "") -> Mapping:
    """``values`` if it is a mapping whose keys are all ``allowed``; else raise."""
    if not isinstance(values, Mapping):
        raise ConfigError(f"must be a table/object, got {values!r}", key=where or None)
    for key in values:
        if key not in allowed:
            raise UnknownKeyError(
                f"unknown key '{_join(where, str(key))}' (valid: {sorted(allowed)})"
            )
    return values


def dataclass_from_mapping(
    cls: type[_T], values: Any, where: str = "", convert: Mapping[str, Any] | None = None
) -> _T:
    """``cls(**values)`` for a (frozen) dataclass; unknown keys and bad values raise.

    Parameters
    ----------
    cls : dataclass type
    values : mapping of field name → value
    where : str
        Dotted name of the section (for messages), e.g. ``"failsafe"``.
    convert : mapping of field name → callable, optional
        Applied to those fields' values first (e.g. a string to an enum).

    Raises
    ------
    UnknownKeyError
        A key that is not a field of ``cls``.
    ConfigError
        The dataclass refused a value (its ``__post_init__`` message as the reason).
    """
    names = {f.name for f in dataclasses.fields(cls)}
    kw = dict(check_keys(values, names, where))
    for key, fn in (convert or {}).items():
        if key in kw and kw[key] is not None:
            kw[key] = fn(kw[key])
    try:
        return cls(**kw)
    except ConfigError:
        raise
    except (TypeError, ValueError) as exc:
        raise ConfigError(str(exc), key=where or None) from None


def vec3(value: Any, where: str) -> tuple[float, float, float]:
    """Three finite numbers (a position or vector from a config), else :class:`ConfigError`."""
    try:
        out = tuple(float(x) for x in value)
    except (TypeError, ValueError):
        raise ConfigError(f"must be 3 numbers, got {value!r}", key=where) from None
    if len(out) != 3 or not all(math.isfinite(x) for x in out):
        raise ConfigError(f"must be 3 finite numbers, got {value!r}", key=where)
    return out  # type: ignore[return-value]


def check_numbers(
    obj: Any, names: Iterable[str], *, positive: bool = False, as_float: bool = False
) -> None:
    """Check the fields ``names`` of ``obj`` (a dataclass, in its ``__post_init__``): each a
    finite real number (not a bool), ``>= 0``, or ``> 0`` with ``positive``; else a
    ``ValueError`` naming the field. With ``as_float`` each is stored as a ``float`` (also
    on a frozen dataclass)."""
    for name in names:
        value = getattr(obj, name)
        if isinstance(value, bool) or not isinstance(value, numbers.Real):
            raise ValueError(f"{name} must be a number, got {value!r}")
        if not (math.isfinite(value) and (value > 0.0 if positive else value >= 0.0)):
            bound = "positive" if positive else ">= 0"
            raise ValueError(f"{name} must be finite and {bound}, got {value!r}")
        if as_float:
            object.__setattr__(obj, name, float(value))
