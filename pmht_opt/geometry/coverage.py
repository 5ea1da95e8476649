"""The one coverage measure: how far each locale is from the paths, and which are missed.

A locale counts as visited when some path passes within its sensor radius, measured on the segments
between consecutive positions (a platform flies straight between them), not only at the positions.
Every part of the package that asks "is this locale covered" (results, planners, figures, exports)
asks here, with :data:`COVERAGE_RTOL` as the one slack: a plan made to touch a disc at exactly its
radius meets it to its solver's tolerance.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from pmht_opt.geometry.plane import point_polyline_distance

#: Relative slack of the coverage test: a locale within ``radius * (1 + COVERAGE_RTOL)`` is covered.
COVERAGE_RTOL = 1e-6


def miss_distances(locales: np.ndarray, lines: Sequence[np.ndarray] | np.ndarray) -> np.ndarray:
    """``(N,)`` distance of each of ``locales (N, 2)`` to the nearest of ``lines`` (polylines
    ``(K, 2)``, or an ``(M, T+1, 2)`` array of paths), measured on their segments; ``inf`` without
    lines."""
    paths = [np.asarray(line, dtype=float) for line in lines]
    if not paths:
        return np.full(np.shape(locales)[0], np.inf)
    return np.min([point_polyline_distance(locales, p) for p in paths], axis=0)


def missed(miss: np.ndarray, radius: float | np.ndarray) -> np.ndarray:
    """Indices of the locales whose miss distances ``miss (N,)`` exceed their ``radius`` (one number,
    or one per locale) beyond :data:`COVERAGE_RTOL`."""
    return np.flatnonzero(miss > np.asarray(radius, dtype=float) * (1.0 + COVERAGE_RTOL))


def missed_locales(
    locales: np.ndarray, lines: Sequence[np.ndarray] | np.ndarray, radius: float | np.ndarray
) -> np.ndarray:
    """Indices of the locales further than their ``radius`` from every one of ``lines``."""
    return missed(miss_distances(locales, lines), radius)


__all__ = ["COVERAGE_RTOL", "miss_distances", "missed", "missed_locales"]
