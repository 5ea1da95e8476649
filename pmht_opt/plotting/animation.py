"""An animation of the EM: the paths after each iteration, in motion (the paper's Figure 1 shows
them after a few selected iterations).

Frames are the positions a plan keeps with ``PMHTConfig(snapshots=...)`` (key 0 is the standing
start, key ``k`` the paths after iteration ``k``); the view is fixed on the scenario's area, and each
frame's title gives the iteration, the penalty ``r`` it used (annealing widens it at first) and the
coverage reached. Written as a GIF with matplotlib's ``FuncAnimation`` and its Pillow writer.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from pmht_opt import validation
from pmht_opt.exceptions import ConfigError
from pmht_opt.geometry.coverage import missed_locales
from pmht_opt.plotting import (
    AREA_STYLE,
    MISSED_STYLE,
    VIEW_MARGIN,
    draw_constraint,
    platform_colour,
    pyplot,
)
from pmht_opt.scenario import Scenario

#: Most frames in one animation: every iteration up to here, then evenly spaced ones.
MAX_FRAMES = 60


def pick_frames(iterations: Sequence[int], limit: int = MAX_FRAMES) -> list[int]:
    """At most ``limit`` of ``iterations`` (sorted): the early ones, where the paths change most, all
    of them; later ones evenly spaced; always the last."""
    its = sorted(iterations)
    if len(its) <= limit:
        return its
    head = its[: limit // 2]
    rest = its[limit // 2 :]
    step = len(rest) / (limit - len(head))
    tail = [rest[min(int(i * step), len(rest) - 1)] for i in range(limit - len(head))]
    return sorted({*head, *tail, its[-1]})


def animate_iterations(
    scenario: Scenario,
    snapshots: Mapping[int, np.ndarray],
    path: str | Path,
    *,
    constraints: Sequence[Any] = (),
    r: Sequence[float] | None = None,
    title: str = "",
    fps: int = 6,
    dpi: int = 100,
    labels: tuple[str, str] = ("x", "y"),
) -> Path:
    """Write a GIF of the paths after each EM iteration.

    Parameters
    ----------
    scenario
        The scenario planned.
    snapshots
        Iteration -> positions ``(M, T+1, 2)`` (:attr:`~pmht_opt.PlanResult.snapshots`).
    path
        The ``.gif`` to write.
    constraints
        Drawn underneath, as in the figures.
    r
        The penalty of each iteration (``IterationHistory.r``: index ``k`` is iteration ``k``), shown
        in the titles.
    title
        A heading above the iteration counter.
    fps, dpi
        Frames per second and resolution; the last frame is held for two seconds.
    labels
        Axis labels.
    """
    if not snapshots:
        raise ConfigError("snapshots: no iterations to animate; plan with PMHTConfig(snapshots=...).")
    plt = pyplot()
    from matplotlib.animation import FuncAnimation, PillowWriter

    frames = pick_frames(list(snapshots))
    last = frames[-1]
    hold = [last] * (2 * fps)
    fig, ax = plt.subplots(figsize=(5.6, 5.6))
    try:
        M = next(iter(snapshots.values())).shape[0]
        paths, ends, missed = _stage(ax, scenario, M, constraints, labels)
        heading = ax.set_title("", fontsize=9)
        z = scenario.locales
        rho = scenario.coverage_radius

        def draw(k: int) -> list[Any]:
            pos = np.asarray(snapshots[k])
            for m in range(M):
                paths[m].set_data(pos[m, :, 0], pos[m, :, 1])
                ends[m].set_data([pos[m, -1, 0]], [pos[m, -1, 1]])
            miss = np.zeros(z.shape[0], dtype=bool)
            miss[missed_locales(z, pos, rho)] = True
            missed.set_data(z[miss, 0], z[miss, 1])
            what = "the standing start" if k == 0 else f"after iteration {k} of {last}"
            penalty = f", r = {r[k]:.3g}" if r is not None and k < len(r) and k > 0 else ""
            lead = f"{title}\n" if title else ""
            heading.set_text(f"{lead}EM paths {what}{penalty}, coverage {1 - miss.mean():.0%}")
            return [*paths, *ends, missed, heading]

        anim = FuncAnimation(fig, draw, frames=[*frames, *hold], blit=False)
        out = validation.file_path("path", path)
        # The layout is fixed once, for every frame: fitted to the longest heading (the last
        # iteration's, with its penalty), so no frame's title is cut off.
        draw(last)
        fig.tight_layout()
        with validation.writing(out) as part:
            anim.save(part, writer=PillowWriter(fps=fps), dpi=dpi)
    finally:
        plt.close(fig)
    return out


def _stage(
    ax: Any, scenario: Scenario, M: int, constraints: Sequence[Any], labels: tuple[str, str]
) -> tuple[list[Any], list[Any], Any]:
    """What stays still on ``ax``: constraints, the area (the view fixed on it), locales, starts and the
    legend; and the artists every frame moves: each platform's path and end, and the missed locales."""
    from matplotlib.patches import Rectangle

    for con in constraints:
        draw_constraint(con, ax)
    bounds = scenario.bounds
    assert bounds is not None
    xmin, xmax, ymin, ymax = bounds
    ax.add_patch(Rectangle((xmin, ymin), xmax - xmin, ymax - ymin, **AREA_STYLE))
    pad = VIEW_MARGIN * max(xmax - xmin, ymax - ymin, 1e-12)
    ax.set_xlim(xmin - pad, xmax + pad)
    ax.set_ylim(ymin - pad, ymax + pad)
    ax.set_aspect("equal", adjustable="box")
    ax.set_xlabel(labels[0])
    ax.set_ylabel(labels[1])
    z = scenario.locales
    ax.plot(z[:, 0], z[:, 1], "x", color="k", ms=5, mew=1.0, ls="none", label="locale")
    (missed,) = ax.plot([], [], zorder=2, label=f"missed (> {scenario.radius_text})", **MISSED_STYLE)
    paths = [
        ax.plot([], [], "-", color=platform_colour(m), lw=1.4, label=f"platform {m}")[0] for m in range(M)
    ]
    ends = [ax.plot([], [], "o", color=platform_colour(m), ms=6, mec="k", mew=0.5)[0] for m in range(M)]
    s = scenario.start_positions
    for m in range(M):
        ax.plot(*s[m], marker="s", ms=8, mfc="white", mec=platform_colour(m), mew=2.0, zorder=4)
    ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.1), ncol=min(M + 2, 4), fontsize=7, frameon=False)
    return paths, ends, missed


def animate_plan(result: Any, path: str | Path, unit: str = "", **options: Any) -> Path:
    """Write a GIF of the EM iterations of a plan made with ``PMHTConfig(snapshots=...)``
    (:func:`animate_iterations`)."""
    sc = result.scenario
    labels = ("east (m)", "north (m)") if unit.strip(" ()") == "m" else ("x", "y")
    options.setdefault("title", sc.name)
    return animate_iterations(
        sc,
        result.snapshots,
        path,
        constraints=result.constraints,
        r=list(result.history.r),
        labels=labels,
        **options,
    )
