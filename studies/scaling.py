"""Study 3: scaling (``pmht-opt study scaling``): plan time and peak memory as N, T and M grow.

Scenarios: ``N`` locales uniform in the 10 x 10 box and ``M`` starts uniform in it
(``numpy.random.default_rng(seed)``), horizon ``T``, the default planner configuration (annealed,
platform prior re-estimated) for ``--iterations`` EM iterations.

Every measurement is one plan in a fresh spawned child process, one at a time: the child times
:func:`~pmht_opt.plan_pmht` and reads its own peak resident set size (``ru_maxrss``), so runs do not
share caches, pools or heap. ``base_rss_mib`` is the child's peak before planning (interpreter,
libraries, scenario); ``peak_rss_mib`` is the peak after.

Parts, in order:

Backends
    The headline size (N = 1000, T = 2000, M = 10) once per backend in ``--backends`` with the gated
    E-step; the fastest is used for everything else.
Headline
    ``--reps`` plans of the headline size with the fastest backend, gated and dense E-step (median
    reported), against the target of 60 s and 4 GiB.
Sweeps
    N, T and M one at a time around a moderate centre (N = 500, T = 1000, M = 5), gated and dense,
    ``--reps`` each; slopes of log time (and log memory above the baseline) against log size by
    least squares.
Agreement
    Gated and dense plans of the headline and of the centre in one child each: largest position
    difference, objective history, MAP assignment and visit times, and the final E-step recomputed
    both ways (W, WZ, normalisers, platform prior, MAP).

Outputs in ``--out``: ``scaling.jsonl`` (one row per child; resumable, ``--fresh`` starts afresh),
``scaling.json`` (settings, provenance, summaries, slopes, agreement, target), ``scaling.md`` (tables)
and ``scaling.png`` (log-log time and memory per sweep with fitted slopes). ``--quick`` runs a small
version in well under a minute.

    pmht-opt study scaling --out studies/results/scaling
    python studies/scaling.py [--reps 3] [--backends kalman clarabel osqp] [--quick] [--fresh]
"""

from __future__ import annotations

import argparse
import concurrent.futures as cf
import contextlib
import dataclasses
import math
import platform
import sys
import time
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import scipy.sparse as sp

from pmht_opt.exceptions import ConfigError
from pmht_opt.mstep import MSTEP_BACKENDS, available_backends
from pmht_opt.scenario import Scenario
from studies.options import RunOptions, positive_int
from studies.provenance import load_average, provenance
from studies.report import median, write_json, write_text
from studies.store import Schema
from studies.trials import Check, TrialTable, local_executor, run_trials

TARGET_SECONDS = 60.0
TARGET_GIB = 4.0
GATES = ("auto", "off")


@dataclass(frozen=True)
class Design:
    """Sizes of one run of the study."""

    headline: tuple[int, int, int]
    centre: tuple[int, int, int]
    n_values: tuple[int, ...]
    t_values: tuple[int, ...]
    m_values: tuple[int, ...]
    iterations: int
    reps: int

    def sweep_points(self) -> dict[str, list[tuple[int, int, int]]]:
        """``(N, T, M)`` of each sweep; all pass through the centre."""
        n0, t0, m0 = self.centre
        return {
            "N": [(n, t0, m0) for n in self.n_values],
            "T": [(n0, t, m0) for t in self.t_values],
            "M": [(n0, t0, m) for m in self.m_values],
        }


FULL = Design(
    headline=(1000, 2000, 10),
    centre=(500, 1000, 5),
    n_values=(100, 200, 500, 1000),
    t_values=(250, 500, 1000, 2000),
    m_values=(1, 2, 5, 10),
    iterations=100,
    reps=3,
)
QUICK = Design(
    headline=(60, 80, 3),
    centre=(40, 60, 2),
    n_values=(20, 40),
    t_values=(30, 60),
    m_values=(1, 2),
    iterations=8,
    reps=1,
)


def scaling_scenario(n_locales: int, horizon: int, n_platforms: int, seed: int) -> Scenario:
    """Random locales and starts in the 10 x 10 box."""
    rng = np.random.default_rng(seed)
    return Scenario(
        locales=rng.uniform(0.0, 10.0, (n_locales, 2)),
        starts=rng.uniform(0.0, 10.0, (n_platforms, 2)),
        horizon=horizon,
        bounds=(0.0, 10.0, 0.0, 10.0),
        name=f"random N={n_locales} T={horizon} M={n_platforms} seed={seed}",
    )


def _rss_mib() -> float:
    """Peak resident set size of this process so far (Linux reports KiB, macOS bytes)."""
    import resource  # POSIX only, and only in the child that measures

    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return float(peak) / (1024.0 * 1024.0 if platform.system() == "Darwin" else 1024.0)


def _config(solver: str, gate: str, iterations: int) -> Any:
    from pmht_opt.planner import PMHTConfig

    return PMHTConfig(solver=solver, max_iter=iterations, estep_gate=None if gate == "off" else "auto")


def trial(
    task: str,
    n_locales: int,
    horizon: int,
    n_platforms: int,
    solver: str,
    gate: str,
    iterations: int,
    seed: int,
    rep: int,
) -> dict[str, Any]:
    """One child's work: ``task="time"`` times one plan, ``task="agree"`` compares gated and dense."""
    sc = scaling_scenario(n_locales, horizon, n_platforms, seed)
    if task == "time":
        return _time_plan(sc, solver, gate, iterations)
    if task == "agree":
        return _agreement(sc, solver, iterations)
    raise ConfigError(f"scaling: unknown task {task!r}.")


@contextlib.contextmanager
def _gated_calls() -> Iterator[list[bool]]:
    """Record, for every E-step the planner runs, whether it was gated (the dense one may run instead)."""
    import pmht_opt.planner as planner

    real = planner.estep
    seen: list[bool] = []

    def spy(*args: Any, **kwargs: Any) -> Any:
        out = real(*args, **kwargs)
        seen.append(bool(out.gated))
        return out

    planner.estep = spy
    try:
        yield seen
    finally:
        planner.estep = real


def _time_plan(sc: Scenario, solver: str, gate: str, iterations: int) -> dict[str, Any]:
    from pmht_opt.planner import plan_pmht

    cfg = _config(solver, gate, iterations)
    base = _rss_mib()
    with _gated_calls() as seen:
        started = time.perf_counter()
        res = plan_pmht(sc, cfg)
        wall = time.perf_counter() - started
    peak = _rss_mib()
    e = res.history.estep_time
    settled = cfg.anneal.end(sc.r, iterations)
    return {
        "wall_s": wall,
        "estep_s": float(np.sum(e)),
        "estep_settled_s": float(np.sum(e[settled:])),
        "mstep_s": float(np.sum(res.history.mstep_time)),
        "estep_calls": len(seen),
        "estep_gated_calls": int(sum(seen)),
        "base_rss_mib": base,
        "peak_rss_mib": peak,
        "distance": float(res.total_distance),
        "objective": float(res.history.objective[-1]),
    }


def _agreement(sc: Scenario, solver: str, iterations: int) -> dict[str, Any]:
    from pmht_opt.estep import estep, safe_log
    from pmht_opt.model import POS
    from pmht_opt.planner import plan_pmht

    gated = plan_pmht(sc, _config(solver, "auto", iterations))
    dense = plan_pmht(sc, _config(solver, "off", iterations))
    obj_g, obj_d = gated.history.objective, dense.history.objective
    # The last E-step of the dense plan recomputed both ways.
    args = (sc.locales, dense.states[:, 1:, POS], None, safe_log(dense.platform_prior), sc.r)
    ed = estep(*args)
    t0 = time.perf_counter()
    eg = estep(*args, gate="auto")
    t_gated = time.perf_counter() - t0
    t0 = time.perf_counter()
    estep(*args)
    t_dense = time.perf_counter() - t0

    def rel(a: np.ndarray, b: np.ndarray) -> float:
        return float(np.max(np.abs(a - b)) / max(float(np.max(np.abs(b))), 1e-300))

    nnz = int(eg.weights.nnz) if isinstance(eg.weights, sp.csr_matrix) else int(eg.weights.size)
    return {
        "pos_max_diff": float(np.max(np.abs(gated.positions - dense.positions))),
        "objective_rel_diff": rel(obj_g, obj_d),
        "assignment_equal": bool(np.array_equal(gated.assignment, dense.assignment)),
        "visit_time_equal": bool(np.array_equal(gated.visit_time, dense.visit_time)),
        "distance_gated": float(gated.total_distance),
        "distance_dense": float(dense.total_distance),
        "wall_gated_s": float(gated.wall_time),
        "wall_dense_s": float(dense.wall_time),
        "estep_gated": bool(eg.gated),
        "estep_kept_fraction": float(nnz) / float(eg.weights.shape[0] * eg.weights.shape[1]),
        "estep_W_rel": rel(eg.W, ed.W),
        "estep_WZ_rel": rel(eg.WZ, ed.WZ),
        "estep_lse_max_abs": float(np.max(np.abs(eg.log_normaliser - ed.log_normaliser))),
        "estep_platform_prior_max_abs": float(np.max(np.abs(eg.platform_prior() - ed.platform_prior()))),
        "estep_map_equal": bool(
            all(np.array_equal(a, b) for a, b in zip(eg.map_assignment(), ed.map_assignment(), strict=True))
        ),
        "estep_time_gated_s": t_gated,
        "estep_time_dense_s": t_dense,
    }


_TIMES = (
    "wall_s",
    "estep_s",
    "estep_settled_s",
    "mstep_s",
    "base_rss_mib",
    "peak_rss_mib",
    "wall_gated_s",
    "wall_dense_s",
    "estep_time_gated_s",
    "estep_time_dense_s",
)
TABLE = TrialTable(
    name="scaling",
    fn=trial,
    schema=Schema(
        params={
            "task": "str",
            "n_locales": "int",
            "horizon": "int",
            "n_platforms": "int",
            "solver": "str",
            "gate": "str",
            "iterations": "int",
            "seed": "int",
            "rep": "int",
        },
        # Two tasks with different results: every column is optional.
        values={
            **{name: "float?" for name in _TIMES},
            "estep_calls": "int?",
            "estep_gated_calls": "int?",
            "distance": "float?",
            "objective": "float?",
            "pos_max_diff": "float?",
            "objective_rel_diff": "float?",
            "assignment_equal": "bool?",
            "visit_time_equal": "bool?",
            "distance_gated": "float?",
            "distance_dense": "float?",
            "estep_gated": "bool?",
            "estep_kept_fraction": "float?",
            "estep_W_rel": "float?",
            "estep_WZ_rel": "float?",
            "estep_lse_max_abs": "float?",
            "estep_platform_prior_max_abs": "float?",
            "estep_map_equal": "bool?",
        },
    ),
    checks={name: Check("skip", reason="time and memory are measurements of the machine") for name in _TIMES},
)


def verify_executor() -> cf.Executor:
    """One worker, a new spawned process for every trial: how the study runs its trials."""
    return local_executor(1, max_tasks_per_child=1)


def _params(
    task: str, size: tuple[int, int, int], solver: str, gate: str, iterations: int, seed: int, rep: int
) -> dict[str, Any]:
    n, t, m = size
    return {
        "task": task,
        "n_locales": n,
        "horizon": t,
        "n_platforms": m,
        "solver": solver,
        "gate": gate,
        "iterations": iterations,
        "seed": seed,
        "rep": rep,
    }


def _ok(rows: Sequence[Mapping[str, Any]]) -> list[Mapping[str, Any]]:
    return [r for r in rows if not r.get("error")]


def _median(rows: Sequence[Mapping[str, Any]], key: str) -> float:
    return median(r[key] for r in rows)


def _select(rows: Sequence[Mapping[str, Any]], **match: Any) -> list[Mapping[str, Any]]:
    return [r for r in _ok(rows) if all(r[k] == v for k, v in match.items())]


def summarise_point(rows: Sequence[Mapping[str, Any]]) -> dict[str, Any]:
    """Medians over the repeats of one (size, solver, gate)."""
    return {
        "runs": len(rows),
        "wall_s": _median(rows, "wall_s"),
        "wall_s_all": [float(r["wall_s"]) for r in rows],
        "estep_s": _median(rows, "estep_s"),
        "estep_settled_s": _median(rows, "estep_settled_s"),
        "mstep_s": _median(rows, "mstep_s"),
        "estep_calls": _median(rows, "estep_calls"),
        "estep_gated_calls": _median(rows, "estep_gated_calls"),
        "peak_rss_mib": _median(rows, "peak_rss_mib"),
        "base_rss_mib": _median(rows, "base_rss_mib"),
    }


def fit_slope(x: Sequence[float], y: Sequence[float]) -> float:
    """Least-squares slope of ``log y`` against ``log x`` (NaN with fewer than two usable points)."""
    xa, ya = np.asarray(x, dtype=float), np.asarray(y, dtype=float)
    ok = np.isfinite(xa) & np.isfinite(ya) & (xa > 0) & (ya > 0)
    if np.sum(ok) < 2 or np.ptp(np.log(xa[ok])) == 0:
        return math.nan
    return float(np.polyfit(np.log(xa[ok]), np.log(ya[ok]), 1)[0])


def run(
    out_dir: Path,
    design: Design = FULL,
    backends: Sequence[str] = ("kalman", "clarabel", "osqp"),
    seed: int = 0,
    progress: bool = True,
    resume: bool = True,
) -> tuple[dict[str, Any], list[Path]]:
    """Run the study into ``out_dir``; returns the summary written to ``scaling.json`` and the paths
    written."""
    installed = set(available_backends())
    backends = [b for b in backends if b in installed]
    if not backends:
        raise ConfigError(f"backends: none installed; available: {', '.join(sorted(installed))}.")
    out_dir = Path(out_dir)
    it, reps = design.iterations, design.reps
    load_start = load_average()

    def measure(trials: list[dict[str, Any]], label: str, first: bool = False) -> list[dict[str, Any]]:
        ex = verify_executor()
        try:
            return run_trials(
                TABLE,
                trials,
                out_dir,
                executor=ex,
                progress=progress,
                label=label,
                resume=resume or not first,
            )
        finally:
            ex.shutdown(wait=True, cancel_futures=True)

    # 1. Backends at the headline size.
    head = design.headline
    rows = measure(
        [_params("time", head, b, "auto", it, seed, 0) for b in backends], "scaling: backends", first=True
    )
    by_backend = {b: summarise_point(_select(rows, solver=b)) for b in backends}
    timed = {b: s["wall_s"] for b, s in by_backend.items() if s["runs"]}
    if not timed:
        raise ConfigError("scaling: every backend failed at the headline size; see scaling.jsonl.")
    fastest = min(timed, key=lambda b: timed[b])

    # 2. Headline repeats, gated and dense.
    rows = measure(
        [_params("time", head, fastest, g, it, seed, k) for g in GATES for k in range(reps)],
        "scaling: headline",
    )
    headline = {g: summarise_point(_select(rows, gate=g)) for g in GATES}

    # 3. Sweeps.
    sweeps = design.sweep_points()
    points = list(dict.fromkeys(p for pts in sweeps.values() for p in pts))
    rows = measure(
        [_params("time", p, fastest, g, it, seed, k) for p in points for g in GATES for k in range(reps)],
        "scaling: sweeps",
    )
    sweep_out: dict[str, Any] = {}
    for axis, pts in sweeps.items():
        idx = "NTM".index(axis)
        entry: dict[str, Any] = {"points": [list(p) for p in pts]}
        for g in GATES:
            stats = [
                summarise_point(_select(rows, n_locales=a, horizon=b, n_platforms=c, gate=g))
                for a, b, c in pts
            ]
            xs = [p[idx] for p in pts]
            entry[g] = {
                "stats": stats,
                "time_slope": fit_slope(xs, [s["wall_s"] for s in stats]),
                "memory_slope": fit_slope(xs, [s["peak_rss_mib"] - s["base_rss_mib"] for s in stats]),
            }
        sweep_out[axis] = entry

    # 4. Agreement.
    rows = measure(
        [_params("agree", p, fastest, "both", it, seed, 0) for p in dict.fromkeys([head, design.centre])],
        "scaling: agreement",
    )
    agreement = [
        {
            k: v
            for k, v in r.items()
            if k not in ("task", "gate", "rep", "trial", "error", "error_class", "run")
        }
        for r in _ok(rows)
    ]

    gated = headline["auto"]
    prov = provenance()
    summary: dict[str, Any] = {
        "design": {
            "headline": list(design.headline),
            "centre": list(design.centre),
            "iterations": it,
            "reps": reps,
            "seed": seed,
            "config": "PMHTConfig defaults (annealed, platform prior re-estimated), threads = min(M, cores)",
        },
        "machine": {
            "cores": prov["cpu_count"],
            "platform": prov["platform"],
            # Other work on the machine skews the times: the 1-minute load average before and after.
            "load_average_start": load_start,
            "load_average_end": load_average(),
        },
        "provenance": prov,
        "backends": by_backend,
        "fastest": fastest,
        "headline": headline,
        "target": {
            "seconds": TARGET_SECONDS,
            "gib": TARGET_GIB,
            # Only the full study's headline is the target's problem.
            "met": None
            if (design.headline, it) != (FULL.headline, FULL.iterations)
            else bool(
                gated["runs"] > 0
                and gated["wall_s"] <= TARGET_SECONDS
                and gated["peak_rss_mib"] <= TARGET_GIB * 1024
            ),
        },
        "sweeps": sweep_out,
        "agreement": agreement,
    }
    text = markdown(summary)
    written = [
        TABLE.path(out_dir),
        write_json(out_dir / "scaling.json", summary),
        write_text(out_dir / "scaling.md", text + "\n"),
        plot(summary, out_dir / "scaling.png"),
    ]
    if progress:
        print(text)
    return summary, written


def _fmt(x: Any, digits: int = 3) -> str:
    if x is None or (isinstance(x, float) and not math.isfinite(x)):
        return "-"
    if isinstance(x, bool):
        return "yes" if x else "no"
    if isinstance(x, float):
        return f"{x:.{digits}g}"
    return str(x)


def _row(cells: Sequence[Any]) -> str:
    return "| " + " | ".join(str(c) for c in cells) + " |"


def _header(cells: Sequence[str]) -> list[str]:
    return [_row(cells), _row(["---"] * len(cells))]


def markdown(summary: Mapping[str, Any]) -> str:
    """The summary as markdown tables."""
    d = summary["design"]
    machine = summary["machine"]
    n, t, m = d["headline"]
    lines = [
        f"# Scaling: N = {n}, T = {t}, M = {m}, {d['iterations']} EM iterations",
        "",
        f"Machine: {machine['cores']} cores, {machine['platform']}; load average "
        f"{_fmt(machine['load_average_start'])} at the start, "
        f"{_fmt(machine['load_average_end'])} at the end. "
        "Each plan in a fresh child process; "
        "peak RSS of that child. Medians over the repeats.",
        "",
        "## Backends (gated E-step, one run each)",
        "",
        *_header(["backend", "wall (s)", "E-step (s)", "M-step (s)", "peak RSS (MiB)"]),
    ]
    for b, s in summary["backends"].items():
        cells = [s["wall_s"], s["estep_s"], s["mstep_s"], s["peak_rss_mib"]]
        lines.append(_row([b, *(_fmt(c) for c in cells)]))
    tgt = summary["target"]
    lines += [
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
                    "gated" if g == "auto" else "dense",
                    s["runs"],
                    _fmt(s["wall_s"]),
                    ", ".join(_fmt(w) for w in s["wall_s_all"]),
                    _fmt(s["estep_s"]),
                    _fmt(s["estep_settled_s"]),
                    f"{_fmt(s['estep_gated_calls'])} of {_fmt(s['estep_calls'])}",
                    _fmt(s["mstep_s"]),
                    _fmt(s["peak_rss_mib"]),
                ]
            )
        )
    verdict = {True: "met", False: "NOT met", None: "not measured (not the target's size)"}[tgt["met"]]
    lines += [
        "",
        f"Target at N = 1000, T = 2000, M = 10, 100 iterations: <= {tgt['seconds']:g} s and "
        f"<= {tgt['gib']:g} GiB (gated): {verdict}.",
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
                        "gated" if g == "auto" else "dense",
                        sizes,
                        " ".join(_fmt(s["wall_s"]) for s in e["stats"]),
                        " ".join(_fmt(s["peak_rss_mib"], 4) for s in e["stats"]),
                        _fmt(e["time_slope"]),
                        _fmt(e["memory_slope"]),
                    ]
                )
            )
    lines += [
        "",
        "## Gated against dense",
        "",
        "Whole plans (gated and dense), then the last E-step of the dense plan recomputed both ways.",
        "",
        *_header(
            [
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
        ),
    ]
    for a in summary["agreement"]:
        lines.append(
            _row(
                [
                    f"{a['n_locales']}x{a['horizon']}x{a['n_platforms']}",
                    _fmt(a["pos_max_diff"], 2),
                    _fmt(a["objective_rel_diff"], 2),
                    _fmt(a["assignment_equal"]),
                    _fmt(a["visit_time_equal"]),
                    _fmt(a["estep_kept_fraction"], 2),
                    _fmt(a["estep_W_rel"], 2),
                    _fmt(a["estep_WZ_rel"], 2),
                    _fmt(a["estep_lse_max_abs"], 2),
                    _fmt(a["estep_platform_prior_max_abs"], 2),
                    _fmt(a["estep_map_equal"]),
                    f"{a['estep_time_gated_s']:.3f} / {a['estep_time_dense_s']:.3f}",
                ]
            )
        )
    return "\n".join(lines)


def plot(summary: Mapping[str, Any], path: Path) -> Path:
    """Log-log time (top) and peak memory above the baseline (bottom) per sweep, with fitted slopes."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.ticker import NullFormatter

    fig, axes = plt.subplots(2, 3, figsize=(15, 8.5))
    for col, (axis, entry) in enumerate(summary["sweeps"].items()):
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
                ok = np.isfinite(ys) & (ys > 0)  # log axes: a run within the baseline has no point
                ax.plot(np.asarray(xs)[ok], ys[ok], style, label=f"{name}: slope {_fmt(slope, 2)}")
                ax.set_xscale("log")
                if np.any(ok):
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
    h = summary["headline"]["auto"]
    n, t, m = summary["design"]["headline"]
    fig.suptitle(
        f"Scaling ({summary['fastest']}, {summary['design']['iterations']} iterations); "
        f"headline N={n}, T={t}, M={m}: {_fmt(h['wall_s'])} s, {_fmt(h['peak_rss_mib'], 4)} MiB peak (gated)"
    )
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


@dataclass(frozen=True)
class Options:
    """Options of ``pmht-opt study scaling``."""

    quick: bool = False
    reps: int | None = None
    iterations: int | None = None
    backends: tuple[str, ...] = ("kalman", "clarabel", "osqp")
    seed: int = 0

    def __post_init__(self) -> None:
        if self.reps is not None:
            positive_int("--reps", self.reps)
        if self.iterations is not None:
            positive_int("--iterations", self.iterations)
        positive_int("--seed", self.seed, minimum=0)

    def design(self) -> Design:
        """The sizes to run: the full or quick design with the repeats and iterations asked for."""
        base = QUICK if self.quick else FULL
        return dataclasses.replace(
            base, reps=self.reps or base.reps, iterations=self.iterations or base.iterations
        )

    @staticmethod
    def add_arguments(p: argparse.ArgumentParser) -> None:
        """The command-line options of this study."""
        p.add_argument(
            "--quick", action="store_true", help="a small version (well under a minute), for tests"
        )
        p.add_argument("--reps", type=int, default=None, help="repeats per measurement (default 3; quick 1)")
        p.add_argument(
            "--iterations", type=int, default=None, help="EM iterations per plan (default 100; quick 8)"
        )
        p.add_argument(
            "--backends",
            nargs="+",
            default=["kalman", "clarabel", "osqp"],
            choices=sorted(MSTEP_BACKENDS),
            help="backends compared at the headline size; the fastest runs the rest",
        )
        p.add_argument("--seed", type=int, default=0, help="scenario seed (default 0)")

    @classmethod
    def from_args(cls, ns: argparse.Namespace) -> Options:
        """The options from parsed arguments."""
        return cls(bool(ns.quick), ns.reps, ns.iterations, tuple(ns.backends), int(ns.seed))


def main(run_options: RunOptions, options: Options) -> list[Path]:
    """``pmht-opt study scaling``: plans are timed one at a time, each in a fresh process."""
    if run_options.dask_scheduler:
        raise ConfigError("--dask-scheduler: scaling times plans on this machine, one at a time.")
    if run_options.workers > 1 and not run_options.quiet:
        print("scaling: plans are timed one at a time (fresh process each); --workers is not used.")
    out = run_options.prepare()
    _, written = run(
        out,
        options.design(),
        backends=options.backends,
        seed=options.seed,
        progress=not run_options.quiet,
        resume=not run_options.fresh,
    )
    return written


if __name__ == "__main__":
    from studies.cli import main as cli_main

    sys.exit(
        cli_main(["scaling", "--out", str(Path(__file__).parent / "results" / "scaling"), *sys.argv[1:]])
    )
