"""The scaling study's summary as markdown tables (``scaling.md``).

The text says how each number was measured (a fresh child per plan, medians over repeats) so the
file can be read without the code.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

from studies.scaling_study.design import GATES

Summary = Mapping[str, Any]


def fmt(x: Any, digits: int = 3) -> str:
    """A cell: ``-`` for none, yes/no for booleans, ``digits`` significant digits for floats."""
    if x is None or (isinstance(x, float) and not math.isfinite(x)):
        return "-"
    if isinstance(x, bool):
        return "yes" if x else "no"
    if isinstance(x, float):
        return f"{x:.{digits}g}"
    return str(x)


def _row(cells: Sequence[Any]) -> str:
    """One table row."""
    return "| " + " | ".join(str(c) for c in cells) + " |"


def _header(cells: Sequence[str]) -> list[str]:
    """A table's header and its rule."""
    return [_row(cells), _row(["---"] * len(cells))]


def _gate_name(gate: str) -> str:
    """The E-step mode as the tables name it."""
    return "gated" if gate == "auto" else "dense"


def backends_section(summary: Summary) -> list[str]:
    """The title, how the study measures, and the backends at the headline size."""
    d, machine = summary["design"], summary["machine"]
    n, t, m = d["headline"]
    lines = [
        f"# Scaling: N = {n}, T = {t}, M = {m}, {d['iterations']} EM iterations",
        "",
        f"Machine: {machine['cores']} cores, {machine['platform']}; load average "
        f"{fmt(machine['load_average_start'])} at the start, "
        f"{fmt(machine['load_average_end'])} at the end. "
        "Each plan in a fresh child process; "
        "peak RSS of that child. Medians over the repeats.",
        "",
        "## Backends (gated E-step, one run each)",
        "",
        *_header(["backend", "wall (s)", "E-step (s)", "M-step (s)", "peak RSS (MiB)"]),
    ]
    for b, s in summary["backends"].items():
        cells = [s["wall_s"], s["estep_s"], s["mstep_s"], s["peak_rss_mib"]]
        lines.append(_row([b, *(fmt(c) for c in cells)]))
    return lines


def headline_section(summary: Summary) -> list[str]:
    """The headline size with the fastest backend, gated and dense, and the target's verdict."""
    lines = [
        "",
        f"## Headline ({summary['fastest']})",
        "",
        *_header(
            [
                "E-step",
                "runs",
                "wall (s), median",
                "all runs (s)",
                "E-step (s)",
                "E-step after annealing (s)",
                "E-steps gated",
                "M-step (s)",
                "peak RSS (MiB)",
            ]
        ),
    ]
    for g, s in summary["headline"].items():
        lines.append(
            _row(
                [
                    _gate_name(g),
                    s["runs"],
                    fmt(s["wall_s"]),
                    ", ".join(fmt(w) for w in s["wall_s_all"]),
                    fmt(s["estep_s"]),
                    fmt(s["estep_settled_s"]),
                    f"{fmt(s['estep_gated_calls'])} of {fmt(s['estep_calls'])}",
                    fmt(s["mstep_s"]),
                    fmt(s["peak_rss_mib"]),
                ]
            )
        )
    tgt = summary["target"]
    verdict = {True: "met", False: "NOT met", None: "not measured (not the target's size)"}[tgt["met"]]
    return [
        *lines,
        "",
        f"Target at N = 1000, T = 2000, M = 10, 100 iterations: <= {tgt['seconds']:g} s and "
        f"<= {tgt['gib']:g} GiB (gated): {verdict}.",
    ]


def sweeps_section(summary: Summary) -> list[str]:
    """Each sweep, gated and dense: times and memory per point, and the two slopes."""
    lines = [
        "",
        "## Sweeps (slopes of log time / log memory above the baseline against log size)",
        "",
        *_header(["sweep", "E-step", "N x T x M", "wall (s)", "peak RSS (MiB)", "time slope", "mem. slope"]),
    ]
    for axis, entry in summary["sweeps"].items():
        sizes = " ".join("x".join(str(v) for v in p) for p in entry["points"])
        for g in GATES:
            e = entry[g]
            lines.append(
                _row(
                    [
                        axis,
                        _gate_name(g),
                        sizes,
                        " ".join(fmt(s["wall_s"]) for s in e["stats"]),
                        " ".join(fmt(s["peak_rss_mib"], 4) for s in e["stats"]),
                        fmt(e["time_slope"]),
                        fmt(e["memory_slope"]),
                    ]
                )
            )
    return lines


_AGREEMENT_HEADER = [
    "size (N x T x M)",
    "max position diff",
    "objective rel diff",
    "MAP same",
    "visit times same",
    "E-step kept fraction",
    "W rel",
    "WZ rel",
    "log-normaliser abs",
    "platform prior abs",
    "E-step MAP same",
    "E-step time gated / dense (s)",
]


def agreement_section(summary: Summary) -> list[str]:
    """Gated against dense: whole plans, then one E-step computed both ways."""
    lines = [
        "",
        "## Gated against dense",
        "",
        "Whole plans (gated and dense), then the last E-step of the dense plan recomputed both ways.",
        "",
        *_header(_AGREEMENT_HEADER),
    ]
    for a in summary["agreement"]:
        lines.append(
            _row(
                [
                    f"{a['n_locales']}x{a['horizon']}x{a['n_platforms']}",
                    fmt(a["pos_max_diff"], 2),
                    fmt(a["objective_rel_diff"], 2),
                    fmt(a["assignment_equal"]),
                    fmt(a["visit_time_equal"]),
                    fmt(a["estep_kept_fraction"], 2),
                    fmt(a["estep_W_rel"], 2),
                    fmt(a["estep_WZ_rel"], 2),
                    fmt(a["estep_lse_max_abs"], 2),
                    fmt(a["estep_platform_prior_max_abs"], 2),
                    fmt(a["estep_map_equal"]),
                    f"{a['estep_time_gated_s']:.3f} / {a['estep_time_dense_s']:.3f}",
                ]
            )
        )
    return lines


def scale_section(summary: Summary) -> list[str]:
    """The scale point's plan (plain EM, gated) and the target's verdict."""
    s = summary["scale"]
    n, t, m = s["size"]
    tgt = s["target"]
    verdict = tgt["verdict"]
    lines = [
        "",
        f"## Scale point N = {n}, T = {t}, M = {m} ({summary['fastest']}, plain EM, gated E-step)",
        "",
        *_header(["runs", "wall (s)", "E-step (s)", "E-steps gated", "M-step (s)", "peak RSS (MiB)"]),
        _row(
            [
                s["runs"],
                fmt(s["wall_s"]),
                fmt(s["estep_s"]),
                f"{fmt(s['estep_gated_calls'])} of {fmt(s['estep_calls'])}",
                fmt(s["mstep_s"]),
                fmt(s["peak_rss_mib"]),
            ]
        ),
        "",
        f"Target: <= {tgt['seconds']:g} s and <= {tgt['gib']:g} GiB: {verdict}.",
    ]
    return lines + [f"Failed: {e}" for e in s["errors"]]


def markdown(summary: Summary) -> str:
    """The summary as markdown tables."""
    lines = backends_section(summary)
    lines += headline_section(summary)
    lines += sweeps_section(summary)
    lines += agreement_section(summary)
    lines += scale_section(summary)
    return "\n".join(lines)
