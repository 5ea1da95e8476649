"""Validation of constraint parameters: each helper returns the clean value or raises ``ConfigError``
naming the parameter."""

from __future__ import annotations

from typing import Any

import numpy as np

from pmht_opt.exceptions import ConfigError


def positive_number(name: str, value: Any, allow_zero: bool = False) -> float:
    """``value`` as a finite positive float, or :class:`ConfigError` naming ``name``."""
    try:
        out = float(value)
    except (TypeError, ValueError):
        raise ConfigError(f"{name}: expected a finite positive number, got {value!r}.") from None
    if not np.isfinite(out) or out < 0 or (out == 0 and not allow_zero):
        kind = "non-negative" if allow_zero else "positive"
        raise ConfigError(f"{name}: expected a finite {kind} number, got {value!r}.")
    return out


def point_array(name: str, value: Any, shape: tuple[int, ...]) -> np.ndarray:
    """``value`` as a finite float array of ``shape`` (``-1`` any length), or :class:`ConfigError`."""
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise ConfigError(f"{name}: expected numbers, got {value!r}.") from None
    ok = arr.ndim == len(shape) and all(s in (-1, d) for s, d in zip(shape, arr.shape, strict=True))
    if not ok:
        raise ConfigError(f"{name}: expected shape {shape}, got {arr.shape}.")
    if not np.all(np.isfinite(arr)):
        raise ConfigError(f"{name}: contains NaN or infinite values.")
    return arr


def check_sides(name: str, sides: Any) -> int:
    """Polygon side count: an integer >= 4 (a square is the coarsest useful inner approximation)."""
    if isinstance(sides, bool) or not isinstance(sides, (int, np.integer)) or sides < 4:
        raise ConfigError(f"{name}.sides: expected an integer >= 4, got {sides!r}.")
    return int(sides)


def check_platforms(owner: str, platforms: Any) -> tuple[int, ...] | None:
    """Platform indices a constraint binds (``None``: all), or :class:`ConfigError` naming ``owner``."""
    if platforms is None:
        return None
    try:
        plats = tuple(int(p) for p in np.atleast_1d(platforms))
    except (TypeError, ValueError):
        raise ConfigError(f"{owner}.platforms: expected platform indices, got {platforms!r}.") from None
    if any(p < 0 for p in plats):
        raise ConfigError(f"{owner}.platforms: indices must be >= 0, got {plats}.")
    return plats
