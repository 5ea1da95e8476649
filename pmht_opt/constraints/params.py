"""Validation of constraint parameters: each helper returns the clean value or raises ``ConfigError``
naming the parameter.

Numbers must be real numbers (``int``, ``float`` or numpy's): a string that looks like a number or a
boolean is a mistake in the caller's data, not a value, and is refused rather than converted.
"""

from __future__ import annotations

import numbers
from typing import Any

import numpy as np

from pmht_opt import validation
from pmht_opt.exceptions import ConfigError

#: Largest length, radius, speed or acceleration a constraint takes: the coordinates' range
#: (:data:`pmht_opt.validation.COORDINATE_MAX`); beyond it a limit never binds and only spoils the
#: scaling of the rows.
LENGTH_MAX = validation.COORDINATE_MAX
#: Largest weight of a soft constraint: the M-step cost's terms are of order 1 to 1e4 on the paper's
#: scenarios, and a slack cost beyond 1e12 of them leaves nothing of the cost for the solver to read.
WEIGHT_MAX = 1e12
#: Most sides an inner polygon may have: beyond this the rows cost far more than the 2e-5 relative
#: margin they save over a 512-gon.
MAX_SIDES = 512


def is_real(value: Any) -> bool:
    """Whether ``value`` is a real number (not a bool, not a string)."""
    return isinstance(value, numbers.Real) and not isinstance(value, (bool, np.bool_))


def real_array(name: str, value: Any) -> np.ndarray:
    """``value`` (a number or a nested sequence of numbers) as a float array, or :class:`ConfigError`
    (:func:`pmht_opt.validation.real_array`)."""
    return validation.real_array(name, value, ConfigError)


def positive_number(name: str, value: Any, allow_zero: bool = False, maximum: float = LENGTH_MAX) -> float:
    """``value`` as a finite positive float up to ``maximum``, or :class:`ConfigError` naming ``name``."""
    return validation.real(name, value, ConfigError, 0.0, maximum, lo_open=not allow_zero)


def limits(owner: str, value: Any) -> np.ndarray:
    """A positive limit up to :data:`LENGTH_MAX`, or one per platform, as a 1-D float array."""
    message = (
        f"{owner}: expected a finite positive number up to {LENGTH_MAX:g} or one per platform, "
        f"got {validation.describe(value)}."
    )
    try:
        arr = np.atleast_1d(real_array(owner, value))
    except ConfigError:
        raise ConfigError(message) from None
    if arr.ndim != 1 or arr.size == 0 or not np.all(np.isfinite(arr)) or np.any(arr <= 0):
        raise ConfigError(message)
    if np.any(arr > LENGTH_MAX):
        raise ConfigError(message)
    return arr


def point_array(name: str, value: Any, shape: tuple[int, ...]) -> np.ndarray:
    """``value`` as a finite float array of ``shape`` (``-1`` any length), every value at most
    :data:`~pmht_opt.validation.COORDINATE_MAX` in magnitude, or :class:`ConfigError`."""
    arr = real_array(name, value)
    ok = arr.ndim == len(shape) and all(s in (-1, d) for s, d in zip(shape, arr.shape, strict=True))
    if not ok:
        raise ConfigError(f"{name}: expected shape {shape}, got {arr.shape}.")
    if not np.all(np.isfinite(arr)):
        raise ConfigError(f"{name}: contains NaN or infinite values.")
    return validation.bounded(name, arr, validation.COORDINATE_MAX, ConfigError)


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
