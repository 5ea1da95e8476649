r"""Plane geometry of discs and polylines: distances to segments, coverage in passing, the unit box.

A polyline *covers* a disc :math:`D = \{p : \lVert p - z \rVert \le \rho\}` when one of its segments
:math:`[a, b]` comes within :math:`\rho` of the centre. The closest point of a segment to :math:`z` is
:math:`a + t (b - a)` with :math:`t = \operatorname{clip}((z - a)\cdot(b - a) / \lVert b - a\rVert^2, 0, 1)`,
so the test is one projection per (disc, segment) pair; it is vectorised over all pairs here, which is
quadratic in memory only through the ``(N, S)`` distance table (a few MB at a thousand discs).

Every search in this package runs on a *normalised* copy of the problem: coordinates shifted and
scaled so the bounding box of the discs and starts has its longer side equal to one, then rounded to a
grid of :data:`GRID` (about ``1e-9``). Two problems that differ only by units (every coordinate and
radius times the same factor) then give bit-identical normalised data, hence the same searches, the
same integer costs and the same tours: the rounding absorbs the last-bit differences that the
multiplication leaves, except for a coordinate within those few units of the last place of a point
halfway between two grid points, which rounds to either. The grid is coarse to make that rare: on a
grid of ``2**-40`` one of bonus1000's 2,000 normalised coordinates fell on such a point at scales
0.01 and 100, and the search then took another path (2.3% apart); at ``2**-30`` a coordinate does so
with a chance of about ``1e-7``. Each radius is rounded down and then less one grid step, which is
more than a centre moves (half a step on each axis): every normalised disc lies inside its own, so a
tour that meets the normalised discs meets the user's.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: Distances (unit box) closer than this count as equal when choosing where a polyline meets a disc.
TIE = 1e-12
#: Grid of the normalised coordinates (a power of two, so the rounding is exact; module notes).
GRID = 2.0**-30


@dataclass(frozen=True)
class Frame:
    """The affine map between the user's coordinates and the unit box: ``x = origin + side * u``."""

    origin: np.ndarray
    side: float

    def to_unit(self, x: np.ndarray) -> np.ndarray:
        """Coordinates ``x`` (any shape ``(..., 2)``) in the unit box, rounded to :data:`GRID`."""
        return np.round((np.asarray(x, dtype=float) - self.origin) / self.side / GRID) * GRID

    def length_to_unit(self, r: np.ndarray) -> np.ndarray:
        """Radii in the unit box, rounded *down* to :data:`GRID` and then one step less (at least 0):
        a disc around a centre rounded by :meth:`to_unit` is inside the user's (module notes)."""
        return np.maximum(np.floor(np.asarray(r, dtype=float) / self.side / GRID) - 1.0, 0.0) * GRID

    def from_unit(self, u: np.ndarray) -> np.ndarray:
        """Coordinates back in the user's units."""
        return self.origin + self.side * np.asarray(u, dtype=float)


def unit_frame(starts: np.ndarray, centres: np.ndarray, radii: np.ndarray) -> Frame:
    """The frame whose unit box holds every start and every disc, its longer side of length one."""
    lo = np.minimum(starts.min(axis=0), (centres - radii[:, None]).min(axis=0, initial=np.inf))
    hi = np.maximum(starts.max(axis=0), (centres + radii[:, None]).max(axis=0, initial=-np.inf))
    side = float(np.max(hi - lo))
    return Frame(origin=lo, side=side if side > 0 else 1.0)


def segment_distances(z: np.ndarray, a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Distances ``(N, S)`` of points ``z`` ``(N, 2)`` to segments ``[a_s, b_s]`` and the parameters ``t``.

    ``t`` in ``[0, 1]`` places the closest point at ``a + t (b - a)``; a degenerate segment (``a = b``)
    has ``t = 0``. Written per coordinate (no ``(N, S, 2)`` temporaries): the searches call it often.
    """
    dx, dy = b[:, 0] - a[:, 0], b[:, 1] - a[:, 1]
    dd = dx * dx + dy * dy
    inv = np.divide(1.0, dd, out=np.zeros_like(dd), where=dd > 0)
    rx = z[:, 0:1] - a[None, :, 0]
    ry = z[:, 1:2] - a[None, :, 1]
    t = np.minimum(np.maximum((rx * dx + ry * dy) * inv, 0.0), 1.0)
    return np.hypot(rx - t * dx, ry - t * dy), t


def polyline_length(vertices: np.ndarray) -> float:
    """Length of the polyline through ``vertices`` ``(K, 2)`` in order (0 for fewer than two)."""
    if vertices.shape[0] < 2:
        return 0.0
    step = np.diff(vertices, axis=0)
    return float(np.hypot(step[:, 0], step[:, 1]).sum())


@dataclass(frozen=True)
class Passing:
    """Where a polyline passes closest to each disc centre.

    Attributes
    ----------
    distance
        ``(N,)`` distance of each centre to the polyline.
    position
        ``(N,)`` the closest point's place along the polyline: segment index plus ``t`` (a single
        vertex polyline gives 0).
    point
        ``(N, 2)`` the closest point itself.
    """

    distance: np.ndarray
    position: np.ndarray
    point: np.ndarray


def passing(centres: np.ndarray, vertices: np.ndarray) -> Passing:
    """Closest approach of the polyline through ``vertices`` ``(K >= 1, 2)`` to every centre.

    Ties between segments (within :data:`TIE`) go to the earliest one: a polyline that runs out and
    back along itself meets a disc on the way out.
    """
    if vertices.shape[0] == 1:
        off = centres - vertices[0]
        return Passing(
            np.hypot(off[:, 0], off[:, 1]), np.zeros(len(centres)), np.repeat(vertices, len(centres), 0)
        )
    a, b = vertices[:-1], vertices[1:]
    dist, t = segment_distances(centres, a, b)
    seg = np.argmax(dist <= dist.min(axis=1, keepdims=True) + TIE, axis=1)
    rows = np.arange(len(centres))
    tt = t[rows, seg]
    point = a[seg] + tt[:, None] * (b[seg] - a[seg])
    return Passing(dist[rows, seg], seg + tt, point)


def inner(radii: np.ndarray) -> np.ndarray:
    """Radii less a hair (``1e-12`` relative plus ``1e-15``): points placed on the circle at this
    radius are inside the disc whatever the rounding of their coordinates."""
    return radii - (1e-12 * radii + 1e-15)


def pull_inside(points: np.ndarray, centres: np.ndarray, radii: np.ndarray) -> np.ndarray:
    """Points moved radially just inside their discs (:func:`inner`) where they lie beyond that."""
    off = points - centres
    norm = np.hypot(off[:, 0], off[:, 1])
    rin = inner(radii)
    over = norm > rin
    out = points.copy()
    out[over] = centres[over] + off[over] * (rin[over] / norm[over])[:, None]
    return out
