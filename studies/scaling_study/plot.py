"""The scaling study's figure (``scaling.png``): log-log time and memory per sweep, with slopes.

Log axes make a power law a straight line whose slope is the fitted exponent, so the legend's slopes
can be checked by eye; memory is drawn above the child's baseline, the part the plan itself needs.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from studies.scaling_study.design import GATES
from studies.scaling_study.markdown import fmt


def _sweep_column(axes: Any, col: int, axis: str, entry: Mapping[str, Any]) -> None:
    """One sweep: wall time (top) and memory above the baseline (bottom), gated and dense."""
    from matplotlib.ticker import NullFormatter

    idx = "NTM".index(axis)
    xs = [p[idx] for p in entry["points"]]
    fixed = ", ".join(f"{k} = {v}" for k, v in zip("NTM", entry["points"][0], strict=True) if k != axis)
    for g, style in zip(GATES, ("o-", "s--"), strict=True):
        e = entry[g]
        name = "gated" if g == "auto" else "dense"
        walls = np.array([s["wall_s"] for s in e["stats"]])
        mems = np.array([s["peak_rss_mib"] - s["base_rss_mib"] for s in e["stats"]])
        panels = ((axes[0, col], walls, e["time_slope"]), (axes[1, col], mems, e["memory_slope"]))
        for ax, ys, slope in panels:
            shown = np.isfinite(ys) & (ys > 0)  # log axes: a run within the baseline has no point
            ax.plot(np.asarray(xs)[shown], ys[shown], style, label=f"{name}: slope {fmt(slope, 2)}")
            ax.set_xscale("log")
            if np.any(shown):
                ax.set_yscale("log")
    axes[0, col].set_title(f"{axis} sweep ({fixed})")
    axes[0, col].set_ylabel("plan wall time (s)")
    axes[1, col].set_ylabel("peak RSS above baseline (MiB)")
    for ax in axes[:, col]:
        ax.set_xlabel(axis)
        ax.set_xticks(xs, [str(x) for x in xs])
        ax.xaxis.set_minor_formatter(NullFormatter())
        ax.grid(True, which="both", alpha=0.3)
        ax.legend()


def plot(summary: Mapping[str, Any], path: Path) -> Path:
    """Log-log time (top) and peak memory above the baseline (bottom) per sweep, with fitted slopes."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(2, 3, figsize=(15, 8.5))
    for col, (axis, entry) in enumerate(summary["sweeps"].items()):
        _sweep_column(axes, col, axis, entry)
    h = summary["headline"]["auto"]
    n, t, m = summary["design"]["headline"]
    s = summary["scale"]
    ns, ts, ms = s["size"]
    fig.suptitle(
        f"Scaling ({summary['fastest']}, {summary['design']['iterations']} iterations); "
        f"headline N={n}, T={t}, M={m}: {fmt(h['wall_s'])} s, {fmt(h['peak_rss_mib'], 4)} MiB peak (gated)\n"
        f"scale point N={ns}, T={ts}, M={ms} (plain EM, gated): {fmt(s['wall_s'])} s, "
        f"{fmt(s['peak_rss_mib'], 4)} MiB peak"
    )
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
