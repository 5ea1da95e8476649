"""Keep-out zones: discs and convex polygons.

Staying outside a convex region is not a convex constraint. Each EM iteration replaces it by a
separating half-plane per time step, chosen at the current iterate ``pbar_t`` (the previous M-step's
position): for a disc, the tangent half-plane facing ``pbar_t``, ``n_t . (p_t - c) >= radius`` with
``n_t = (pbar_t - c) / ||pbar_t - c||``; for a polygon, the half-plane of the edge ``pbar_t`` is
furthest outside of (or, if inside, closest to leaving through). Every half-plane lies wholly outside
the obstacle, so every returned position is outside it whatever the iterate was: the linearisation
is conservative. Segments between consecutive positions can still clip a corner of an obstacle;
:meth:`violation` reports those as ``details["segment_cuts"]``.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

from pmht_opt.constraints.base import VIOLATION_TOL, Constraint, ConstraintContext, ConstraintReport
from pmht_opt.constraints.blocks import Block, state_rows
from pmht_opt.constraints.params import point_array, positive_number
from pmht_opt.exceptions import ConfigError, ScenarioError
from pmht_opt.model import POS, PX, PY

if TYPE_CHECKING:
    from pmht_opt.scenario import Scenario


class _Obstacle(Constraint):
    """Shared logic: linearised half-planes per step, exact penetration and segment checks."""

    dynamic = True

    def __init__(self, margin: float = 0.0, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        self.margin = positive_number(f"{type(self).__name__}.margin", margin, allow_zero=True)

    def halfplanes(self, points: np.ndarray, fallback: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Unit normals ``(K, 2)`` and offsets ``(K,)``: ``n . p >= d`` keeps ``p`` outside; chosen at
        ``points (K, 2)``; ``fallback (2,)`` is a point outside used where the choice is degenerate."""
        raise NotImplementedError

    def penetration(self, points: np.ndarray) -> np.ndarray:
        """``(...,)`` how deep each of ``points (..., 2)`` lies inside the obstacle (0 outside)."""
        raise NotImplementedError

    def segment_cuts(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        """Whether each segment ``a[i] -> b[i]`` passes through the obstacle's interior."""
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
            pbar = ctx.states[m, 1:, :][:, POS]
            normals, offsets = self.halfplanes(pbar, ctx.scenario.start_positions[m])
            # n . p >= d + margin  <=>  h - G z >= 0 with G = -n, h = -(d + margin).
            G = state_rows(T, times, np.array([PX, PY]), -normals)
            out.append(Block(m, "nonneg", G, -(offsets + self.margin), times=times))
        return out

    def violation(self, states: np.ndarray, ctx: ConstraintContext) -> ConstraintReport:
        scenario = ctx.scenario
        pos = states[:, :, POS]
        residuals = []
        cuts = 0
        first_cut: tuple[int, int] | None = None
        for m in self.applies_to(scenario):
            residuals.append((m, np.arange(1, pos.shape[1]), self.penetration(pos[m, 1:])))
            cut = self.segment_cuts(pos[m, :-1], pos[m, 1:])
            cuts += int(np.sum(cut))
            if first_cut is None and np.any(cut):
                first_cut = (m, int(np.argmax(cut)) + 1)
        return self._report(residuals, {"segment_cuts": cuts, "first_segment_cut": first_cut})


class CircleObstacle(_Obstacle):
    """A disc ``||p - center|| < radius`` no position may enter (linearised each iteration).

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

    def halfplanes(self, points: np.ndarray, fallback: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        rel = points - self.center
        norm = np.hypot(rel[:, 0], rel[:, 1])
        away = fallback - self.center
        if np.hypot(*away) < 1e-12:
            away = np.array([1.0, 0.0])
        away = away / np.hypot(*away)
        degenerate = norm < 1e-9
        with np.errstate(invalid="ignore", divide="ignore"):
            normals = np.where(degenerate[:, None], away[None, :], rel / norm[:, None])
        return normals, normals @ self.center + self.radius

    def penetration(self, points: np.ndarray) -> np.ndarray:
        rel = np.asarray(points) - self.center
        return np.maximum(self.radius - np.hypot(rel[..., 0], rel[..., 1]), 0.0)

    def segment_cuts(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        d = b - a
        len2 = np.einsum("ij,ij->i", d, d)
        with np.errstate(invalid="ignore", divide="ignore"):
            s = np.einsum("ij,ij->i", self.center - a, d) / len2
        s = np.clip(np.nan_to_num(s, nan=0.0), 0.0, 1.0)
        closest = a + s[:, None] * d
        dist = np.hypot(*(closest - self.center).T)
        return dist < self.radius - VIOLATION_TOL


class PolygonObstacle(_Obstacle):
    """A convex polygon no position may enter (linearised each iteration by one of its edges).

    Parameters
    ----------
    vertices
        ``(K, 2)`` corners of a convex polygon, ``K >= 3``, in either orientation.
    margin
        Extra clearance required beyond the edges.
    soft, weight, platforms
        See :class:`~pmht_opt.constraints.base.Constraint`.
    """

    def __init__(self, vertices: Any, margin: float = 0.0, **kwargs: Any) -> None:
        super().__init__(margin=margin, **kwargs)
        v = point_array("PolygonObstacle.vertices", vertices, (-1, 2))
        if v.shape[0] < 3:
            raise ConfigError(f"PolygonObstacle.vertices: expected at least 3 corners, got {v.shape[0]}.")
        edges = np.roll(v, -1, axis=0) - v
        area2 = float(np.sum(v[:, 0] * np.roll(v[:, 1], -1) - np.roll(v[:, 0], -1) * v[:, 1]))
        if abs(area2) < 1e-12:
            raise ConfigError("PolygonObstacle.vertices: the polygon has no area.")
        if area2 < 0:  # make it counter-clockwise
            v = v[::-1].copy()
            edges = np.roll(v, -1, axis=0) - v
        cross = (
            edges[:, 0] * np.roll(edges, -1, axis=0)[:, 1] - edges[:, 1] * np.roll(edges, -1, axis=0)[:, 0]
        )
        if np.any(cross < -1e-12):
            raise ConfigError("PolygonObstacle.vertices: the polygon is not convex.")
        lengths = np.hypot(edges[:, 0], edges[:, 1])
        if np.any(lengths < 1e-12):
            raise ConfigError("PolygonObstacle.vertices: repeated corner.")
        self.vertices = v
        # Outward unit normals of a counter-clockwise polygon; inside is n . p <= d for every edge.
        self.normals = np.stack([edges[:, 1], -edges[:, 0]], axis=1) / lengths[:, None]
        self.offsets = np.einsum("ij,ij->i", self.normals, v)

    @property
    def name(self) -> str:
        c = self.vertices.mean(axis=0)
        return f"PolygonObstacle({self.vertices.shape[0]} corners around ({c[0]:.3g}, {c[1]:.3g}))"

    def _signed(self, points: np.ndarray) -> np.ndarray:
        return np.asarray(points) @ self.normals.T - self.offsets  # (..., K): > 0 outside that edge

    def halfplanes(self, points: np.ndarray, fallback: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        edge = np.argmax(self._signed(points), axis=1)
        return self.normals[edge], self.offsets[edge]

    def penetration(self, points: np.ndarray) -> np.ndarray:
        return np.maximum(-np.max(self._signed(points), axis=-1), 0.0)

    def segment_cuts(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        # Clip each segment a + s (b - a), s in [0, 1], against the polygon shrunk by the tolerance.
        d = b - a
        num = (self.offsets - VIOLATION_TOL)[None, :] - a @ self.normals.T  # need den * s <= num
        den = d @ self.normals.T
        lo = np.zeros(a.shape[0])
        hi = np.ones(a.shape[0])
        with np.errstate(invalid="ignore", divide="ignore"):
            ratio = num / den
        lo = np.maximum(lo, np.max(np.where(den < 0, ratio, -np.inf), axis=1))
        hi = np.minimum(hi, np.min(np.where(den > 0, ratio, np.inf), axis=1))
        parallel_out = np.any((np.abs(den) <= 1e-15) & (num < 0), axis=1)
        return (lo < hi) & ~parallel_out
