r"""Candidate points of the discs: the discretisation that the generalised TSP chooses from.

A tour through discs is a tour through one point of each disc, so restricting each disc to finitely
many candidates turns the continuous problem into a generalised TSP (Carrabs et al. 2020). Two kinds of
candidate matter:

- points of the disc's own boundary: where a tour that turns at the disc touches it;
- points shared with other discs (in their intersections, the "Steiner zones"): one stop there serves
  every disc that contains it. Each such point is entered in every group whose disc holds it, at
  distance zero from its copies.

The first discretisation is coarse (evenly spaced boundary points and the middle of each pairwise
overlap); later ones are *refined* around the current tour: each disc keeps the point where the current
polyline meets it, so the current tour is itself a solution of the new generalised TSP, and gets
boundary points a shrinking angle :math:`\pm\delta` either side, so the search can slide the touching
points as it reorders.
"""

from __future__ import annotations

import numpy as np

from pmht_opt.tours.gtsp import Candidates


def _boundary(centres: np.ndarray, radii: np.ndarray, angles: np.ndarray) -> np.ndarray:
    """``(N, A, 2)`` points of every disc's boundary at ``angles`` ``(N, A)``."""
    return centres[:, None, :] + radii[:, None, None] * np.stack([np.cos(angles), np.sin(angles)], axis=-1)


def _lens_middles(centres: np.ndarray, radii: np.ndarray) -> np.ndarray:
    """Middle of the overlap of every pair of overlapping discs, on the line through their centres."""
    i, j = np.triu_indices(len(centres), 1)
    off = centres[j] - centres[i]
    d = np.hypot(off[:, 0], off[:, 1])
    keep = (d < radii[i] + radii[j]) & (d > 0)
    i, j, off, d = i[keep], j[keep], off[keep], d[keep]
    lo = np.maximum(d - radii[j], -radii[i])
    hi = np.minimum(d + radii[j], radii[i])
    return centres[i] + ((lo + hi) / 2 / d)[:, None] * off


def with_copies(
    points: np.ndarray, owner: np.ndarray, centres: np.ndarray, radii: np.ndarray, per_group: int
) -> Candidates:
    """Own candidates plus copies of foreign points into the groups of the discs that contain them.

    Each group receives at most ``per_group`` foreign points, those contained in the most discs first
    (ties by index), so a point deep in a many-disc intersection is offered everywhere it serves.
    """
    off = points[:, None, :] - centres[None, :, :]
    inside = np.hypot(off[..., 0], off[..., 1]) <= radii[None, :] * (1 - 1e-9)
    inside[np.arange(len(points)), owner] = False
    depth = inside.sum(axis=1)
    rank = np.lexsort((np.arange(len(points)), -depth))  # deepest first
    extra_pts: list[np.ndarray] = []
    extra_grp: list[np.ndarray] = []
    taken = np.zeros(len(centres), dtype=np.intp)
    for p in rank:
        if depth[p] == 0:
            break
        hosts = np.flatnonzero(inside[p] & (taken < per_group))
        if hosts.size:
            taken[hosts] += 1
            extra_pts.append(np.repeat(points[p][None], hosts.size, axis=0))
            extra_grp.append(hosts)
    pts = np.vstack([points, *extra_pts]) if extra_pts else points
    grp = np.concatenate([owner, *extra_grp]) if extra_grp else owner
    return Candidates(points=pts, group=grp.astype(np.intp))


def initial_candidates(centres: np.ndarray, radii: np.ndarray, k: int, per_group: int) -> Candidates:
    """``k`` evenly spaced boundary points per disc and the middles of pairwise overlaps (shared)."""
    N = len(centres)
    angles = np.tile(2 * np.pi * np.arange(k) / k, (N, 1))
    own = _boundary(centres, radii, angles).reshape(-1, 2)
    owner = np.repeat(np.arange(N), k)
    lens = _lens_middles(centres, radii)
    off = lens[:, None, :] - centres[None, :, :]
    # A lens middle belongs to the discs that contain it: its first holder owns it, the rest copy it.
    holder = np.argmax(np.hypot(off[..., 0], off[..., 1]) <= radii[None, :], axis=1)
    pts = np.vstack([own, lens])
    return with_copies(pts, np.concatenate([owner, holder]), centres, radii, per_group)


def refined_candidates(
    centres: np.ndarray,
    radii: np.ndarray,
    visits: np.ndarray,
    turns: np.ndarray,
    deltas: np.ndarray,
    per_group: int,
) -> Candidates:
    """Candidates around the current tour.

    Parameters
    ----------
    centres, radii
        The discs.
    visits
        ``(N, 2)`` each disc's point on the current polyline (the first candidate of its group).
    turns
        ``(T, 2)`` the current polyline's turn points, offered to every disc that holds them.
    deltas
        Angles either side of each visit point's direction at which boundary points are added.
    per_group
        Foreign points per group at most.
    """
    N = len(centres)
    off = visits - centres
    theta = np.arctan2(off[:, 1], off[:, 0])
    angles = theta[:, None] + np.concatenate([deltas, -deltas])[None, :]
    ring = _boundary(centres, radii, angles)
    own = np.concatenate([visits[:, None, :], ring], axis=1).reshape(-1, 2)
    owner = np.repeat(np.arange(N), 1 + 2 * len(deltas))
    tp = turns.reshape(-1, 2)
    toff = tp[:, None, :] - centres[None, :, :]
    holder = np.argmax(np.hypot(toff[..., 0], toff[..., 1]) <= radii[None, :] * (1 - 1e-9), axis=1)
    held = (np.hypot(toff[..., 0], toff[..., 1]) <= radii[None, :] * (1 - 1e-9)).any(axis=1)
    pts = np.vstack([own, tp[held]])
    return with_copies(pts, np.concatenate([owner, holder[held]]), centres, radii, per_group)
