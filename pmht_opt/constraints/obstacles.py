"""Keep-out zones: discs and convex polygons, kept clear by every position and every segment.

Staying outside a convex region is not a convex constraint. Each EM iteration replaces it by one
separating half-plane per segment ``p_{t-1} -> p_t`` of the path, chosen at that segment of the
current iterate (the previous M-step's path) and imposed on **both** ends of the segment. A half-plane
is convex, so a segment whose two ends lie in it lies in it whole: no segment between consecutive
positions can cut the obstacle, whatever the iterate was. Every half-plane lies wholly outside the
obstacle (it touches it at most), so the linearisation is conservative.

* Disc: the tangent half-plane facing the point of the iterate's segment nearest to the centre,
  ``n . (p - c) >= radius`` with ``n`` from the centre towards that point. Every point of a segment
  that stays outside the disc lies in it, so a feasible iterate stays feasible.
* Polygon: the half-plane of the edge whose line the iterate's segment is furthest outside of (the
  edge maximising the smaller of the two ends' signed distances).

At ``t = 1`` the segment starts at the known start; the start is outside the zone (checked before
planning), and the half-plane is chosen so that it contains it. :meth:`_Obstacle.violation` measures
how deep any position or segment enters the zone, exactly.
"""

from __future__ import annotations

from itertools import combinations
from typing import TYPE_CHECKING, Any

import numpy as np

from pmht_opt.constraints.base import Constraint, ConstraintContext, ConstraintReport
from pmht_opt.constraints.blocks import Block, state_rows
from pmht_opt.constraints.params import point_array, positive_number
from pmht_opt.exceptions import ConfigError, ScenarioError
from pmht_opt.model import POS, PX, PY

if TYPE_CHECKING:
    from pmht_opt.scenario import Scenario


class _Obstacle(Constraint):
    """Shared logic: a half-plane per segment on both its ends, exact depth of positions and segments."""

    dynamic = True

    def __init__(self, margin: float = 0.0, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        self.margin = positive_number(f"{type(self).__name__}.margin", margin, allow_zero=True)

    def halfplanes(self, a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Unit normals ``(K, 2)`` and offsets ``(K,)``: ``n . p >= d`` keeps ``p`` outside, chosen for
        the segments ``a[k] -> b[k]`` (``(K, 2)`` each) so that it contains ``a[k]`` where ``a[k]`` is
        outside the obstacle."""
        raise NotImplementedError

    def penetration(self, points: np.ndarray) -> np.ndarray:
        """``(...,)`` how deep each of ``points (..., 2)`` lies inside the obstacle (0 outside)."""
        raise NotImplementedError

    def segment_depth(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        """``(K,)`` the deepest penetration of any point of each segment ``a[k] -> b[k]``."""
        raise NotImplementedError

    def segment_cuts(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        """Whether each segment ``a[k] -> b[k]`` enters the obstacle's interior."""
        return self.segment_depth(a, b) > 0

    def scale(self, scenario: Scenario) -> float:
        """The obstacle's size, which verification tolerances are relative to."""
        raise NotImplementedError

    def check_scenario(self, scenario: Scenario) -> None:
        super().check_scenario(scenario)
        starts = scenario.start_positions
        depth = self.penetration(starts)
        for m in self.applies_to(scenario):
            if depth[m] > 0:
                x, y = starts[m]
                raise ScenarioError(f"platform {m} starts at ({x:g}, {y:g}), inside {self.name}.")

    def blocks(self, ctx: ConstraintContext) -> list[Block]:
        T = ctx.scenario.horizon
        out = []
        times = np.arange(1, T + 1)
        for m in self.applies_to(ctx.scenario):
            path = ctx.states[m][:, POS]
            normals, offsets = self.halfplanes(path[:-1], path[1:])
            bound = offsets + self.margin
            # n . p_t >= d_t at both ends of segment t: h - G z >= 0 with G = -n, h = -d. At t = 1 the
            # first end is the known start, inside its half-plane by construction: no row.
            ends = state_rows(T, times, np.array([PX, PY]), -normals)
            out.append(Block(m, "nonneg", ends, -bound, times=times))
            if T > 1:
                firsts = state_rows(T, times[:-1], np.array([PX, PY]), -normals[1:])
                out.append(Block(m, "nonneg", firsts, -bound[1:], times=times[1:]))
        return out

    def violation(self, states: np.ndarray, ctx: ConstraintContext) -> ConstraintReport:
        pos = states[:, :, POS]
        residuals = []
        cuts = 0
        for m in self.applies_to(ctx.scenario):
            depth = self.segment_depth(pos[m, :-1], pos[m, 1:])  # segment t covers p_t too
            cuts += int(np.sum(depth > self.penetration(pos[m, 1:])))
            residuals.append((m, np.arange(1, pos.shape[1]), depth))
        return self._report(ctx.scenario, residuals, {"segments_entering": cuts})


class CircleObstacle(_Obstacle):
    """A disc ``||p - center|| < radius`` that no position and no segment of a path may enter.

    Parameters
    ----------
    center, radius
        The disc.
    margin
        Extra clearance required of the positions beyond ``radius``.
    soft, weight, platforms
        See :class:`~pmht_opt.constraints.base.Constraint`.
    """

    def __init__(self, center: Any, radius: float, margin: float = 0.0, **kwargs: Any) -> None:
        super().__init__(margin=margin, **kwargs)
        self.center = point_array("CircleObstacle.center", center, (2,))
        self.radius = positive_number("CircleObstacle.radius", radius)

    @property
    def name(self) -> str:
        return f"CircleObstacle(({self.center[0]:g}, {self.center[1]:g}), {self.radius:g})"

    def scale(self, scenario: Scenario) -> float:
        return self.radius

    def _nearest(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        """``(K, 2)`` the point of each segment nearest to the centre."""
        d = b - a
        len2 = np.einsum("ij,ij->i", d, d)
        with np.errstate(invalid="ignore", divide="ignore"):
            s = np.einsum("ij,ij->i", self.center - a, d) / len2
        s = np.clip(np.nan_to_num(s, nan=0.0, posinf=0.0, neginf=0.0), 0.0, 1.0)
        return a + s[:, None] * d

    def halfplanes(self, a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        near = self._nearest(a, b)
        rel = near - self.center
        norm = np.hypot(rel[:, 0], rel[:, 1])
        # Where the iterate's segment cuts the disc, face its first end instead (outside the disc
        # whenever that end is the start or a feasible position); where even that is the centre, any
        # direction will do.
        cut = norm < self.radius
        rel = np.where(cut[:, None], a - self.center, rel)
        norm = np.hypot(rel[:, 0], rel[:, 1])
        degenerate = norm < 1e-12 * max(1.0, self.radius)
        with np.errstate(invalid="ignore", divide="ignore"):
            normals = np.where(degenerate[:, None], np.array([1.0, 0.0]), rel / norm[:, None])
        return normals, normals @ self.center + self.radius

    def penetration(self, points: np.ndarray) -> np.ndarray:
        rel = np.asarray(points) - self.center
        return np.maximum(self.radius - np.hypot(rel[..., 0], rel[..., 1]), 0.0)

    def segment_depth(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        return self.penetration(self._nearest(a, b))


class PolygonObstacle(_Obstacle):
    """A convex polygon that no position and no segment of a path may enter.

    Parameters
    ----------
    vertices
        ``(K, 2)`` corners of a convex polygon, ``K >= 3``, in either orientation, no three in a line
        and no edge crossing another (a self-intersecting outline such as a pentagram is refused).
    margin
        Extra clearance required beyond the edges.
    soft, weight, platforms
        See :class:`~pmht_opt.constraints.base.Constraint`.
    """

    def __init__(self, vertices: Any, margin: float = 0.0, **kwargs: Any) -> None:
        super().__init__(margin=margin, **kwargs)
        self.vertices = _convex_ccw(point_array("PolygonObstacle.vertices", vertices, (-1, 2)))
        v = self.vertices
        edges = np.roll(v, -1, axis=0) - v
        lengths = np.hypot(edges[:, 0], edges[:, 1])
        # Outward unit normals of a counter-clockwise polygon; inside is n . p <= d for every edge.
        self.normals = np.stack([edges[:, 1], -edges[:, 0]], axis=1) / lengths[:, None]
        self.offsets = np.einsum("ij,ij->i", self.normals, v)

    @property
    def name(self) -> str:
        c = self.vertices.mean(axis=0)
        return f"PolygonObstacle({self.vertices.shape[0]} corners around ({c[0]:.3g}, {c[1]:.3g}))"

    def scale(self, scenario: Scenario) -> float:
        """The radius of the largest disc inside the polygon's bounding box side (its smaller extent)."""
        extent = self.vertices.max(axis=0) - self.vertices.min(axis=0)
        return float(extent.min()) / 2.0

    def _signed(self, points: np.ndarray) -> np.ndarray:
        return np.asarray(points) @ self.normals.T - self.offsets  # (..., K): > 0 outside that edge

    def halfplanes(self, a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        both = np.minimum(self._signed(a), self._signed(b))
        edge = np.argmax(both, axis=1)
        # Where no edge has both ends outside, take the edge the first end is furthest outside of.
        cut = both[np.arange(edge.size), edge] < 0
        edge = np.where(cut, np.argmax(self._signed(a), axis=1), edge)
        return self.normals[edge], self.offsets[edge]

    def penetration(self, points: np.ndarray) -> np.ndarray:
        return np.maximum(-np.max(self._signed(points), axis=-1), 0.0)

    def segment_depth(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        # Along a + s (b - a) the depth min_k (d_k - n_k . p) is concave and piecewise linear in s:
        # its largest value on [0, 1] is at an end or where two of its pieces cross.
        alpha = -self._signed(a)  # (K_seg, E): d_k - n_k . a
        beta = (b - a) @ self.normals.T  # slope: depth falls by beta_k per unit s
        candidates = [np.zeros(a.shape[0]), np.ones(a.shape[0])]
        with np.errstate(invalid="ignore", divide="ignore"):
            for j, k in combinations(range(alpha.shape[1]), 2):
                s = (alpha[:, j] - alpha[:, k]) / (beta[:, j] - beta[:, k])
                candidates.append(np.clip(np.nan_to_num(s, nan=0.0, posinf=0.0, neginf=0.0), 0.0, 1.0))
        best = np.zeros(a.shape[0])
        for s in candidates:
            best = np.maximum(best, np.min(alpha - s[:, None] * beta, axis=1))
        return best


def _convex_ccw(v: np.ndarray) -> np.ndarray:
    """The corners of a convex, simple polygon in counter-clockwise order, or :class:`ConfigError`."""
    name = "PolygonObstacle.vertices"
    if v.shape[0] < 3:
        raise ConfigError(f"{name}: expected at least 3 corners, got {v.shape[0]}.")
    area2 = float(np.sum(v[:, 0] * np.roll(v[:, 1], -1) - np.roll(v[:, 0], -1) * v[:, 1]))
    scale = float(np.max(np.abs(v - v.mean(axis=0)))) ** 2
    if abs(area2) <= 1e-12 * max(scale, 1e-300):
        raise ConfigError(f"{name}: the polygon has no area.")
    if area2 < 0:
        v = v[::-1].copy()
    edges = np.roll(v, -1, axis=0) - v
    if np.any(np.hypot(edges[:, 0], edges[:, 1]) <= 1e-12 * np.sqrt(scale)):
        raise ConfigError(f"{name}: repeated corner.")
    cross = edges[:, 0] * np.roll(edges, -1, axis=0)[:, 1] - edges[:, 1] * np.roll(edges, -1, axis=0)[:, 0]
    if np.any(cross <= 0):
        raise ConfigError(f"{name}: the polygon is not convex (or has three corners in a line).")
    # Every turn is a left turn; a simple convex outline turns through exactly one full circle (a
    # pentagram's turns are left too, but add up to two full circles).
    heading = np.arctan2(edges[:, 1], edges[:, 0])
    turns = np.mod(np.roll(heading, -1) - heading, 2.0 * np.pi)
    if abs(float(turns.sum()) - 2.0 * np.pi) > 1e-6:
        raise ConfigError(
            f"{name}: the outline crosses itself; give the corners of a convex polygon in order."
        )
    return v
