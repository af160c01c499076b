"""Configuration from mappings (TOML/JSON sections), for every config in the project.

One error type, :class:`ConfigError`, that names the file (when there is one), the key
(dotted: ``link.rate``) and the reason; an unknown key raises :class:`UnknownKeyError`,
which is also a ``TypeError`` (like an unknown keyword argument). One builder,
:func:`dataclass_from_mapping`, for frozen parameter dataclasses, and one 3-vector
validator, :func:`vec3`. Pure.

Fields are declared once, with their unit and bounds (PX4's parameter YAML in spirit:
name, unit, min, max, default), by :func:`bounded`::

    @dataclass(frozen=True)
    class LinkConfig(Checked):
        telemetry_rate_hz: float = bounded(50.0, "Hz", gt=0)
        system_id: int = bounded(1, integer=True, ge=1, le=255)

and checked by one validator, :func:`check_fields` (a :class:`Checked` dataclass runs it
after construction; a class with rules between fields calls it first in its own
``__post_init__``). A value out of bounds raises :class:`ConfigError` naming the field and
the bound (``link.system_id: must be an integer in [1, 255], got 0``);
:func:`dataclass_from_mapping` prefixes the section and a loader the file.
:func:`field_bounds` lists the declarations (for the configuration reference and tests).
"""

from __future__ import annotations

import dataclasses
import math
import numbers
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TypeVar

__all__ = [
    "Bounds",
    "Checked",
    "ConfigError",
    "UnknownKeyError",
    "bounded",
    "check_fields",
    "check_keys",
    "check_numbers",
    "dataclass_from_mapping",
    "field_bounds",
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
    except ConfigError as exc:
        if where and exc.key is not None and not exc.key.startswith(f"{where}."):
            raise type(exc)(exc.reason, key=_join(where, exc.key), file=exc.file) from None
        if where and exc.key is None:
            raise type(exc)(exc.reason, key=where, file=exc.file) from None
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


_BOUNDS = "stereo_avoid.bounds"  # dataclass field metadata key


@dataclass(frozen=True)
class Bounds:
    """A numeric field's declaration: unit and bounds (None: no bound on that side).

    Attributes
    ----------
    unit : str
        SI unit or the one the field's name carries (``"m"``, ``"s"``, ``"Hz"``, ``"deg"``,
        ``"px"``); ``""``: dimensionless.
    ge, gt, le, lt : float or None
        Inclusive / exclusive lower and upper bounds.
    integer : bool
        An ``int`` (not a bool, not a float with an integral value).
    finite : bool
        NaN and ±inf refused (the default); False lets +inf through (never NaN).
    optional : bool
        None is allowed (it means "automatic" or "off"; the field's comment says which).
    """

    unit: str = ""
    ge: float | None = None
    gt: float | None = None
    le: float | None = None
    lt: float | None = None
    integer: bool = False
    finite: bool = True
    optional: bool = False

    def describe(self) -> str:
        """The bound in words: ``an integer in [1, 255]``, ``a number > 0 Hz``."""
        kind = "an integer" if self.integer else "a finite number" if self.finite else "a number"
        lo = (self.ge, "[") if self.ge is not None else (self.gt, "(")
        hi = (self.le, "]") if self.le is not None else (self.lt, ")")
        unit = f" {self.unit}" if self.unit else ""
        if lo[0] is not None and hi[0] is not None:
            text = f"{kind} in {lo[1]}{lo[0]:g}, {hi[0]:g}{hi[1]}{unit}"
        elif lo[0] is not None:
            text = f"{kind} {'>=' if lo[1] == '[' else '>'} {lo[0]:g}{unit}"
        elif hi[0] is not None:
            text = f"{kind} {'<=' if hi[1] == ']' else '<'} {hi[0]:g}{unit}"
        else:
            text = f"{kind}{f' [{self.unit}]' if self.unit else ''}"
        return text + (" or None" if self.optional else "")

    def violation(self, value: Any) -> str | None:
        """Why ``value`` is refused, or None."""
        if value is None:
            return None if self.optional else "must not be None"
        if isinstance(value, bool) or not isinstance(value, numbers.Real):
            return f"must be {self.describe()}, got {value!r}"
        if self.integer and not isinstance(value, numbers.Integral):
            return f"must be {self.describe()}, got {value!r}"
        if math.isnan(value) or (self.finite and not math.isfinite(value)):
            return f"must be {self.describe()}, got {value!r}"
        if (
            (self.ge is not None and not value >= self.ge)
            or (self.gt is not None and not value > self.gt)
            or (self.le is not None and not value <= self.le)
            or (self.lt is not None and not value < self.lt)
        ):
            return f"must be {self.describe()}, got {value!r}"
        return None


def bounded(
    default: Any,
    unit: str = "",
    *,
    ge: float | None = None,
    gt: float | None = None,
    le: float | None = None,
    lt: float | None = None,
    integer: bool = False,
    finite: bool = True,
    optional: bool = False,
) -> Any:
    """A dataclass field with ``default`` and its :class:`Bounds` (checked by
    :func:`check_fields`); ``dataclasses.MISSING`` declares a required field."""
    spec = Bounds(unit, ge, gt, le, lt, integer, finite, optional)
    if default is dataclasses.MISSING:
        return dataclasses.field(metadata={_BOUNDS: spec})
    if spec.violation(default) is not None:
        raise ValueError(f"default {default!r} outside its own bounds ({spec.describe()})")
    return dataclasses.field(default=default, metadata={_BOUNDS: spec})


def field_bounds(cls_or_obj: Any) -> dict[str, Bounds]:
    """The declared :class:`Bounds` of a dataclass's fields, by name."""
    return {
        f.name: f.metadata[_BOUNDS] for f in dataclasses.fields(cls_or_obj) if _BOUNDS in f.metadata
    }


def check_fields(obj: Any) -> None:
    """Check every field of the dataclass ``obj`` declared with :func:`bounded`; the first
    value out of its bounds raises :class:`ConfigError` keyed by the field's name. A
    non-integer field given an ``int`` (TOML ``5`` for ``5.0``) is stored as a ``float``
    (also on a frozen dataclass), so compiled kernels see one type."""
    for name, spec in field_bounds(obj).items():
        value = getattr(obj, name)
        reason = spec.violation(value)
        if reason is not None:
            raise ConfigError(reason, key=name)
        if value is not None and not spec.integer and not isinstance(value, float):
            object.__setattr__(obj, name, float(value))


class Checked:
    """Base of a config dataclass whose fields are all checked by their declarations."""

    def __post_init__(self) -> None:
        check_fields(self)
