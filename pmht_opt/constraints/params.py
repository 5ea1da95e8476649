"""Validation of constraint parameters: each helper returns the clean value or raises ``ConfigError``
naming the parameter.

Numbers must be real numbers (``int``, ``float`` or numpy's): a string that looks like a number or a
boolean is a mistake in the caller's data, not a value, and is refused rather than converted.
"""

from __future__ import annotations

import numbers
from typing import Any

import numpy as np

from pmht_opt.exceptions import ConfigError

#: Most sides an inner polygon may have: beyond this the rows cost far more than the 2e-5 relative
#: margin they save over a 512-gon.
MAX_SIDES = 512


def is_real(value: Any) -> bool:
    """Whether ``value`` is a real number (not a bool, not a string)."""
    return isinstance(value, numbers.Real) and not isinstance(value, (bool, np.bool_))


def real_array(name: str, value: Any) -> np.ndarray:
    """``value`` (a number or a nested sequence of numbers) as a float array, or :class:`ConfigError`."""
    if isinstance(value, (str, bytes)):
        raise ConfigError(f"{name}: expected numbers, got the string {value!r}.")
    try:
        arr = np.asarray(value)
    except (TypeError, ValueError):
        raise ConfigError(f"{name}: expected numbers, got {value!r}.") from None
    if arr.dtype == object:
        flat = list(np.ravel(arr))
        if not all(is_real(v) for v in flat):
            raise ConfigError(f"{name}: expected numbers, got {value!r}.")
        arr = np.asarray(flat, dtype=float).reshape(arr.shape)
    if arr.dtype.kind not in "iuf":
        raise ConfigError(f"{name}: expected numbers, got {value!r}.")
    return arr.astype(float)


def positive_number(name: str, value: Any, allow_zero: bool = False) -> float:
    """``value`` as a finite positive float, or :class:`ConfigError` naming ``name``."""
    kind = "non-negative" if allow_zero else "positive"
    if not is_real(value):
        raise ConfigError(f"{name}: expected a finite {kind} number, got {value!r}.")
    out = float(value)
    if not np.isfinite(out) or out < 0 or (out == 0 and not allow_zero):
        raise ConfigError(f"{name}: expected a finite {kind} number, got {value!r}.")
    return out


def limits(owner: str, value: Any) -> np.ndarray:
    """A positive limit, or one per platform, as a 1-D float array."""
    message = f"{owner}: expected a finite positive number or one per platform, got {value!r}."
    try:
        arr = np.atleast_1d(real_array(owner, value))
    except ConfigError:
        raise ConfigError(message) from None
    if arr.ndim != 1 or arr.size == 0 or not np.all(np.isfinite(arr)) or np.any(arr <= 0):
        raise ConfigError(message)
    return arr


def point_array(name: str, value: Any, shape: tuple[int, ...]) -> np.ndarray:
    """``value`` as a finite float array of ``shape`` (``-1`` any length), or :class:`ConfigError`."""
    arr = real_array(name, value)
    ok = arr.ndim == len(shape) and all(s in (-1, d) for s, d in zip(shape, arr.shape, strict=True))
    if not ok:
        raise ConfigError(f"{name}: expected shape {shape}, got {arr.shape}.")
    if not np.all(np.isfinite(arr)):
        raise ConfigError(f"{name}: contains NaN or infinite values.")
    return arr


def check_sides(name: str, sides: Any) -> int:
    """Polygon side count: an integer from 4 (the coarsest useful inner approximation) to
    :data:`MAX_SIDES`."""
    if isinstance(sides, (bool, np.bool_)) or not isinstance(sides, (int, np.integer)):
        raise ConfigError(f"{name}.sides: expected an integer from 4 to {MAX_SIDES}, got {sides!r}.")
    if not 4 <= sides <= MAX_SIDES:
        raise ConfigError(f"{name}.sides: expected an integer from 4 to {MAX_SIDES}, got {sides!r}.")
    return int(sides)


def check_platforms(owner: str, platforms: Any) -> tuple[int, ...] | None:
    """Platform indices a constraint binds (``None``: all): distinct non-negative integers."""
    if platforms is None:
        return None
    items = [platforms] if np.ndim(platforms) == 0 else list(np.ravel(np.asarray(platforms, dtype=object)))
    bad = [p for p in items if isinstance(p, (bool, np.bool_)) or not isinstance(p, (int, np.integer))]
    if bad or not items:
        raise ConfigError(f"{owner}.platforms: expected platform indices (integers), got {platforms!r}.")
    plats = tuple(int(p) for p in items)
    if any(p < 0 for p in plats):
        raise ConfigError(f"{owner}.platforms: indices must be >= 0, got {plats}.")
    if len(set(plats)) != len(plats):
        raise ConfigError(f"{owner}.platforms: each platform at most once, got {plats}.")
    return plats
