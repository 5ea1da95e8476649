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

Outputs in ``--out``: ``scaling.csv`` (one row per child; resumable, ``--fresh`` starts afresh),
``scaling.json`` (settings, machine, summaries, slopes, agreement, target), ``scaling.md`` (tables)
and ``scaling.png`` (log-log time and memory per sweep with fitted slopes). ``--quick`` runs a small
version in well under a minute.
"""

from __future__ import annotations

import concurrent.futures as cf
import contextlib
import dataclasses
import importlib.metadata
import json
import math
import multiprocessing
import os
import platform
import resource
import time
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import scipy.sparse as sp

from pmht_opt.exceptions import ConfigError
from pmht_opt.montecarlo import run_trials
from pmht_opt.mstep import BACKENDS as MSTEP_BACKENDS
from pmht_opt.mstep import available_backends

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


def scaling_scenario(n_locales: int, horizon: int, n_platforms: int, seed: int) -> Any:
    """Random locales and starts in the 10 x 10 box."""
    from pmht_opt.scenario import Scenario

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


def _time_plan(sc: Any, solver: str, gate: str, iterations: int) -> dict[str, Any]:
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


def _agreement(sc: Any, solver: str, iterations: int) -> dict[str, Any]:
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


def _fresh_child_executor() -> cf.Executor:
    """One worker, a new spawned process for every trial."""
    return cf.ProcessPoolExecutor(1, mp_context=multiprocessing.get_context("spawn"), max_tasks_per_child=1)


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
    vals = [float(r[key]) for r in rows]
    return float(np.median(vals)) if vals else math.nan


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


def _versions() -> dict[str, str]:
    out = {"python": platform.python_version()}
    for name in ("numpy", "scipy", "clarabel", "osqp"):
        try:
            out[name] = importlib.metadata.version(name)
        except importlib.metadata.PackageNotFoundError:
            pass
    return out


def run(
    out_dir: Path,
    design: Design = FULL,
    backends: Sequence[str] = ("kalman", "clarabel", "osqp"),
    seed: int = 0,
    progress: bool = True,
    resume: bool = True,
) -> dict[str, Any]:
    """Run the study into ``out_dir``; returns the summary written to ``scaling.json``."""
    installed = set(available_backends())
    backends = [b for b in backends if b in installed]
    if not backends:
        raise ConfigError(f"backends: none installed; available: {', '.join(sorted(installed))}.")
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    table = out_dir / "scaling.csv"
    it, reps = design.iterations, design.reps
    load_start = os.getloadavg()

    def measure(trials: list[dict[str, Any]], label: str, first: bool = False) -> list[dict[str, Any]]:
        ex = _fresh_child_executor()
        try:
            return run_trials(
                trial, trials, table, executor=ex, progress=progress, label=label, resume=resume or not first
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
        raise ConfigError("scaling: every backend failed at the headline size; see scaling.csv.")
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
        {k: v for k, v in r.items() if k not in ("task", "gate", "rep", "trial", "error")} for r in _ok(rows)
    ]

    gated = headline["auto"]
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
            "cores": os.cpu_count(),
            "platform": platform.platform(),
            # Other work on the machine skews the times: the 1-minute load average before and after.
            "load_average_start": load_start[0],
            "load_average_end": os.getloadavg()[0],
            **_versions(),
        },
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
    (out_dir / "scaling.json").write_text(json.dumps(summary, indent=1) + "\n")
    text = markdown(summary)
    (out_dir / "scaling.md").write_text(text + "\n")
    plot(summary, out_dir / "scaling.png")
    if progress:
        print(text)
    return summary


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
        f"{machine['load_average_start']:.2f} at the start, {machine['load_average_end']:.2f} at the end. "
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


def add_arguments(p: Any) -> None:
    """Options of ``pmht-opt study scaling``."""
    p.add_argument("--quick", action="store_true", help="a small version (well under a minute), for tests")
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


def _positive(name: str, value: Any) -> int | None:
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, int) or value < 1:
        raise ConfigError(f"{name}: expected a positive integer, got {value!r}.")
    return int(value)


def main(args: Any) -> int:
    """``pmht-opt study scaling``."""
    if getattr(args, "dask_scheduler", None):
        raise ConfigError(
            "scaling: timings are taken on this machine, one plan at a time; no --dask-scheduler."
        )
    quiet = bool(getattr(args, "quiet", False))
    if int(getattr(args, "workers", 1)) > 1 and not quiet:
        print("scaling: plans are timed one at a time (fresh process each); --workers is not used.")
    base = QUICK if getattr(args, "quick", False) else FULL
    reps = _positive("reps", getattr(args, "reps", None)) or base.reps
    iterations = _positive("iterations", getattr(args, "iterations", None)) or base.iterations
    design = dataclasses.replace(base, reps=reps, iterations=iterations)
    run(
        Path(args.out),
        design,
        backends=tuple(getattr(args, "backends", ("kalman", "clarabel", "osqp"))),
        seed=int(getattr(args, "seed", 0)),
        progress=not quiet,
        resume=not getattr(args, "fresh", False),
    )
    return 0
