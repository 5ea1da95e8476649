"""How every figure draws things, and matplotlib imported only when a figure is made.

matplotlib is imported inside :func:`pyplot`, with the non-interactive Agg backend, so importing
pmht_opt never touches a display.
"""

from __future__ import annotations

from typing import Any

#: How keep-out zones are drawn: hatched grey, under the paths.
KEEP_OUT_STYLE: dict[str, Any] = {"fc": "0.85", "ec": "0.3", "lw": 0.8, "hatch": "//", "zorder": 0}
#: How area bounds are drawn: a dashed red box.
BOUNDS_STYLE: dict[str, Any] = {"fill": False, "ls": "--", "lw": 1.2, "ec": "C3"}
#: How the scenario's area is drawn: a dotted grey box.
AREA_STYLE: dict[str, Any] = {"fill": False, "ls": ":", "lw": 0.8, "ec": "0.5"}
#: How a missed locale is marked: a red ring around its cross.
MISSED_STYLE: dict[str, Any] = {"marker": "o", "ms": 9, "mfc": "none", "mec": "red", "mew": 1.4, "ls": "none"}
#: Paths reaching further than this fraction of the area's size outside it are clipped, with an inset.
RUNAWAY_FRACTION = 0.25
#: Margin around the area in a clipped view, as a fraction of its size.
VIEW_MARGIN = 0.08


def pyplot() -> Any:
    """``matplotlib.pyplot`` on the Agg backend (unless a backend was chosen already)."""
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    return plt


def figure_formats() -> set[str]:
    """File suffixes (``".png"``, ``".pdf"``, ...) matplotlib can write figures to."""
    pyplot()
    from matplotlib.backend_bases import FigureCanvasBase

    return {f".{k}" for k in FigureCanvasBase.get_supported_filetypes()}


def platform_colour(m: int) -> str:
    """The colour of platform ``m`` in every figure (matplotlib's default cycle)."""
    return f"C{m % 10}"
