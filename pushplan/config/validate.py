"""The one validation style of every input table (scenario, plan, sweep, MuJoCo
settings, command files): a :class:`Table` names its keys with their full path
(``plan.max_step``, ``load[2].dx``) and every check raises :class:`InputError`
with that path and the offending value.

    t = Table(data["plan"], "plan", allowed={"x", "y", "steps"}, required={"x", "y"})
    x = t.number("x")
    steps = t.integer("steps", default=5, minimum=1)
"""

from __future__ import annotations

import math
from typing import Any

from ..errors import InputError
from ..limits import MAX_COUNT

_MISSING = object()


def number(key: str, value: Any, *, positive=False, nonneg=False, lo=None, hi=None, minimum=None, maximum=None) -> float:
    """``value`` as a finite float; open bounds ``lo < v < hi`` (a physical limit the
    value must not reach, Poisson's 0.5) and closed ones ``minimum <= v <= maximum`` (a
    cap of :mod:`pushplan.limits`: "at most", the value itself allowed) when given."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise InputError(f"{key} must be a number, got {short(value)}")
    try:
        v = float(value)
    except OverflowError:  # an integer beyond the largest float, 1.8e308
        raise InputError(f"{key} must be a number a float holds (|v| < 1.8e308), got {short(value)}") from None
    if not math.isfinite(v):
        raise InputError(f"{key} must be finite, got {short(value)}")
    if positive and v <= 0:
        raise InputError(f"{key} must be > 0, got {short(value)}")
    if nonneg and v < 0:
        raise InputError(f"{key} must be >= 0, got {short(value)}")
    if lo is not None and not v > lo:
        raise InputError(f"{key} must be > {lo}, got {short(value)}")
    if hi is not None and not v < hi:
        raise InputError(f"{key} must be < {hi}, got {short(value)}")
    if minimum is not None and not v >= minimum:
        raise InputError(f"{key} must be >= {minimum}, got {short(value)}")
    if maximum is not None and not v <= maximum:
        raise InputError(f"{key} must be <= {maximum} (at most), got {short(value)}")
    return v


def integer(key: str, value: Any, minimum: int = 1, maximum: int | None = None) -> int:
    """``value`` as an int in ``[minimum, maximum]``; ``maximum`` None is
    :data:`~pushplan.limits.MAX_COUNT` (every count has a stated maximum)."""
    maximum = MAX_COUNT if maximum is None else maximum
    if isinstance(value, bool) or not isinstance(value, int):
        raise InputError(f"{key} must be an integer, got {short(value)}")
    if value < minimum:
        raise InputError(f"{key} must be >= {minimum}, got {short(value)}")
    if value > maximum:
        raise InputError(f"{key} must be <= {maximum}, got {short(value)}")
    return value


def short(value: Any) -> str:
    """``repr(value)`` cut to 60 characters (a 5000-digit integer or a huge list in a message)."""
    try:
        text = repr(value)
    except ValueError:  # an int beyond Python's int-to-string digit limit
        return f"an integer of about {int(value.bit_length() * 0.30103)} digits"
    return text if len(text) <= 60 else f"{text[:40]}... ({len(text)} characters)"


def string(key: str, value: Any, *, nonempty=False) -> str:
    if not isinstance(value, str) or (nonempty and not value):
        raise InputError(f"{key} must be a {'non-empty ' if nonempty else ''}string, got {short(value)}")
    return value


def boolean(key: str, value: Any) -> bool:
    if not isinstance(value, bool):
        raise InputError(f"{key} must be true or false, got {short(value)}")
    return value


def choice(key: str, value: Any, options) -> Any:
    if value not in tuple(options):
        raise InputError(f"{key} must be one of {tuple(options)}, got {short(value)}")
    return value


def triple(key: str, value: Any, check) -> tuple:
    """A list of 3 values, each checked by ``check(key[i], v)``."""
    if not isinstance(value, (list, tuple)) or len(value) != 3:
        raise InputError(f"{key} must be a list of 3 values, got {short(value)}")
    return tuple(check(f"{key}[{i}]", v) for i, v in enumerate(value))


def check_keys(key: str, data: Any, allowed, required=()) -> dict:
    """``data`` as a table holding only ``allowed`` keys and every ``required`` one."""
    if not isinstance(data, dict):
        raise InputError(f"{key} must be a table, got {short(data)}")
    prefix = f"{key}." if key else ""
    for k in data:
        if k not in allowed:
            raise InputError(f"unknown key {prefix}{k} (allowed: {', '.join(sorted(allowed))})")
    for k in sorted(required):
        if k not in data:
            raise InputError(f"missing key {prefix}{k}")
    return data


class Table:
    """Typed, key-named access to one input table.

    Parameters
    ----------
    data : dict
        The parsed table.
    name : str
        Its path in messages (``"plan"``, ``"load[2]"``; ``""`` for the top level).
    allowed, required : iterables of str
        Keys it may hold / must hold.
    """

    def __init__(self, data: Any, name: str, allowed, required=()):
        self.data = check_keys(name, data, set(allowed), set(required))
        self.name = name

    def key(self, k: str) -> str:
        return f"{self.name}.{k}" if self.name else k

    def __contains__(self, k: str) -> bool:
        return k in self.data

    def _get(self, k: str, default):
        value = self.data.get(k, default)
        if value is _MISSING:
            raise InputError(f"missing key {self.key(k)}")
        return value

    def number(self, k: str, default=_MISSING, **bounds) -> float:
        return number(self.key(k), self._get(k, default), **bounds)

    def integer(self, k: str, default=_MISSING, minimum: int = 1, maximum: int | None = None) -> int:
        return integer(self.key(k), self._get(k, default), minimum, maximum)

    def string(self, k: str, default=_MISSING, nonempty=False) -> str:
        return string(self.key(k), self._get(k, default), nonempty=nonempty)

    def boolean(self, k: str, default=_MISSING) -> bool:
        return boolean(self.key(k), self._get(k, default))

    def choice(self, k: str, options, default=_MISSING):
        return choice(self.key(k), self._get(k, default), options)

    def triple(self, k: str, check, default=_MISSING) -> tuple:
        return triple(self.key(k), self._get(k, default), check)

    def table(self, k: str, allowed, required=(), default=_MISSING) -> Table:
        return Table(self._get(k, default), self.key(k), allowed, required)


def positive_number(key: str, value: Any) -> float:
    """A :func:`triple` check: a finite number > 0."""
    return number(key, value, positive=True)


def count(key: str, value: Any) -> int:
    """A :func:`triple` check: an integer >= 1."""
    return integer(key, value, 1)
