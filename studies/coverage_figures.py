"""Figures of the coverage study: one per scenario, distance against radius and the Pareto front.

Left panel: mean total distance of every full-coverage planner against the coverage radius. Right
panel: at each radius of the study, every planner as a point (mean coverage at that radius, mean
distance), the full-coverage planners at coverage 1 and the partial ones wherever they land, with the
Pareto front of the points (no other point both shorter and covering more) drawn as a step line;
points more than 1.6 times the shortest distance are left out of the frame.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from studies.report import frame


def pareto_front(points: Sequence[tuple[float, float]]) -> list[tuple[float, float]]:
    """The points ``(coverage, distance)`` that no other point beats on both (more coverage and no
    more distance, or no less coverage and less distance), by increasing coverage."""
    front: list[tuple[float, float]] = []
    for c, d in sorted(points, key=lambda p: (-p[0], p[1])):
        if not front or d < front[-1][1]:
            front.append((c, d))
    return sorted(front)


def _means(df: Any, kind: str) -> dict[tuple[str, float], tuple[float, dict[str, float]]]:
    """``(method, radius) -> (mean distance, mean coverage per radius)`` over the successful trials."""
    out = {}
    ok = df[(df["kind"] == kind) & (df["error"] == "")]
    for (method, radius), g in ok.groupby(["method", "radius"]):
        cov = {key: float(np.mean([c[key] for c in g["coverage_at"]])) for key in g["coverage_at"].iloc[0]}
        out[(str(method), float(radius))] = (float(g["distance"].mean()), cov)
    return out


def write_figures(rows: Sequence[Mapping[str, Any]], radii: Sequence[float], out_dir: Path) -> list[Path]:
    """One PNG per scenario in ``out_dir``: ``coverage_<kind>.png``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    df = frame(rows)
    if df.empty or "distance" not in df:
        return []
    written = []
    for kind in sorted(set(df["kind"])):
        means = _means(df, kind)
        fig, (left, right) = plt.subplots(1, 2, figsize=(12, 5))
        full = sorted({m for m, r in means if r > 0})
        for method in full:
            pts = sorted((r, means[(method, r)][0]) for m, r in means if m == method and r > 0)
            left.plot(*zip(*pts, strict=True), marker="o", label=method)
        left.set(xlabel="coverage radius", ylabel="mean total distance", title=f"{kind}: full coverage")
        left.legend(fontsize=8)
        markers = dict(zip(sorted({m for m, _ in means}), "osD^v<>phX*", strict=False))
        for i, radius in enumerate(radii):
            key = f"{radius:g}"
            pts = []
            for (method, r), (dist, cov) in means.items():
                if r in (0.0, radius) and key in cov:
                    pts.append((cov[key], dist))
                    right.scatter(cov[key], dist, marker=markers[method], color=f"C{i}", s=30)
            front = pareto_front(pts)
            if front:
                right.step(*zip(*front, strict=True), where="pre", color=f"C{i}", label=f"radius {key}")
        shown = [d for (m, r), (d, _) in means.items()]
        low = min(shown)
        right.set_ylim(
            0.95 * low, min(max(shown) * 1.02, 1.6 * low)
        )  # far-off points (e.g. pmht-paper) left out
        for method, mark in markers.items():
            right.scatter([], [], marker=mark, color="0.4", label=method)
        right.set(xlabel="mean coverage at the radius", ylabel="mean total distance", title="Pareto fronts")
        right.legend(fontsize=7, ncol=2)
        fig.tight_layout()
        path = Path(out_dir) / f"coverage_{kind}.png"
        fig.savefig(path, dpi=110)
        plt.close(fig)
        written.append(path)
    return written
