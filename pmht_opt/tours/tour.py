r"""Mutable routes through key discs: the working representation of the local searches.

A route is its start, its *key* discs in order and one turn point per key disc, and, when closed, the
start again. Discs that are not keys are covered in passing; the representation itself does not know
which leg covers them, so every change is checked again for coverage (:meth:`Tour.covered`).

An open route's polyline is stored with its last vertex repeated, as a leg of length zero: a "tail" at
which the route can be extended, and which keeps an empty open route's start in the coverage test
(a disc that contains the start is met by a route of no length).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from pmht_opt.tours.geometry import segment_distances


@dataclass(frozen=True)
class Layout:
    """The normalised problem: starts ``(M, 2)``, closed ``(M,)``, centres ``(N, 2)``, radii ``(N,)``,
    and the route length caps ``(M,)`` (``inf`` for none), or None when no route has one.

    ``solved`` keeps the cone program's turn points of each route's key sequence met so far
    (:func:`~pmht_opt.tours.polish.solve_keys`): a search meets the same routes again and again, and
    the program's answer depends on nothing else, so it is solved once.
    """

    starts: np.ndarray
    closed: np.ndarray
    centres: np.ndarray
    radii: np.ndarray
    caps: np.ndarray | None = None
    solved: dict[tuple[int, tuple[int, ...]], np.ndarray] = field(
        default_factory=dict, compare=False, repr=False
    )

    def excess(self, lengths: np.ndarray) -> float:
        r"""How far routes of these lengths go over their caps in all,
        :math:`\sum_m \max(0, L_m - c_m)` (0 without caps)."""
        if self.caps is None:
            return 0.0
        return float(np.maximum(lengths - self.caps, 0.0).sum())


@dataclass
class Tour:
    """Key discs and their turn points per route (unit box)."""

    layout: Layout
    keys: list[list[int]]
    pts: list[np.ndarray]

    def copy(self) -> Tour:
        """An independent copy."""
        return Tour(self.layout, [list(k) for k in self.keys], [p.copy() for p in self.pts])

    def verts(self, m: int) -> np.ndarray:
        """Polyline of route ``m``: start, turn points, then the start (closed) or the last vertex again."""
        s = self.layout.starts[m][None]
        p = self.pts[m]
        end = s if self.layout.closed[m] else (p[-1:] if len(p) else s)
        return np.vstack([s, p, end])

    def lengths(self) -> np.ndarray:
        """``(M,)`` route lengths."""
        out = np.zeros(len(self.keys))
        for m in range(len(self.keys)):
            v = self.verts(m)
            out[m] = np.hypot(*np.diff(v, axis=0).T).sum()
        return out

    def score(self, objective: str) -> tuple[float, float, float]:
        """Lexicographic score, lower is better: (excess over the caps, total, total), or (excess,
        longest route, total) for ``objective="time"``.

        The excess comes first: a tour within its caps beats every tour that is not, and among tours
        that are not, the one nearer to them wins. Without caps it is always 0 and the order is that
        of the last two entries alone.
        """
        lengths = self.lengths()
        total = float(lengths.sum())
        return (self.layout.excess(lengths), float(lengths.max()) if objective == "time" else total, total)

    def legs(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """All legs: start points ``(L, 2)``, end points ``(L, 2)`` and each leg's route ``(L,)``."""
        A, B, R = [], [], []
        for m in range(len(self.keys)):
            v = self.verts(m)
            A.append(v[:-1])
            B.append(v[1:])
            R.append(np.full(len(v) - 1, m))
        return np.vstack(A), np.vstack(B), np.concatenate(R)

    def covered(self, discs: np.ndarray | None = None) -> np.ndarray:
        """Whether each disc (all, or those listed) is met by some leg."""
        lay = self.layout
        idx = np.arange(len(lay.radii)) if discs is None else np.asarray(discs, dtype=np.intp)
        if idx.size == 0:
            return np.zeros(0, dtype=bool)
        A, B, _ = self.legs()
        d, _ = segment_distances(lay.centres[idx], A, B)
        return bool_any(d <= lay.radii[idx][:, None])

    def key_mask(self) -> np.ndarray:
        """``(N,)`` whether each disc is a key of some route."""
        mask = np.zeros(len(self.layout.radii), dtype=bool)
        for k in self.keys:
            mask[k] = True
        return mask

    def locate(self, disc: int) -> tuple[int, int]:
        """Route and position of a key disc."""
        for m, k in enumerate(self.keys):
            if disc in k:
                return m, k.index(disc)
        raise KeyError(disc)

    def remove(self, m: int, j: int) -> None:
        """Drop the key at position ``j`` of route ``m``."""
        del self.keys[m][j]
        self.pts[m] = np.delete(self.pts[m], j, axis=0)

    def insert(self, m: int, j: int, disc: int, point: np.ndarray) -> None:
        """Make ``disc`` the key at position ``j`` of route ``m`` with turn point ``point``."""
        self.keys[m].insert(j, disc)
        self.pts[m] = np.insert(self.pts[m], j, point, axis=0)


def bool_any(mask: np.ndarray) -> np.ndarray:
    """Row-wise any of a 2-D boolean table (``False`` for rows of no column)."""
    return np.asarray(mask.any(axis=1)) if mask.shape[1] else np.zeros(mask.shape[0], dtype=bool)
