"""Study 3: scaling (``pmht-opt study scaling``): plan time and peak memory as N, T and M grow.

Scenarios: ``N`` locales uniform in the 10 x 10 box and ``M`` starts uniform in it
(``numpy.random.default_rng(seed)``), horizon ``T``, the default planner configuration (annealed,
platform prior re-estimated) for ``--iterations`` EM iterations.

Every measurement is one plan in a fresh spawned child process, one at a time: the child times
:func:`~pmht_opt.plan_pmht` and reads its own peak resident set size (``ru_maxrss``), so runs do not
share caches, pools or heap. ``base_rss_mib`` is the child's peak before planning (interpreter,
libraries, scenario); ``peak_rss_mib`` is the peak after. "E-steps gated" counts, among the E-steps
whose weights feed an M-step (and the initial one), those the gate computed sparsely
(``IterationHistory.estep_gated``).

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

Scale point
    One plan of the largest size (N = 5000, T = 5000, M = 20) with the fastest backend, plain EM
    (``anneal=None``: annealing's first E-steps at a large ``r`` gate almost nothing, and a dense
    E-step at this size holds 5e8 weights) and the gated E-step, against the target of 60 s and
    8 GiB. ``--verify`` may pick its trial: about 6 minutes and 8 GiB on the reference machine.

Outputs in ``--out``: ``scaling.jsonl`` (one row per child; resumable, ``--fresh`` starts afresh),
``scaling.json`` (settings, provenance, summaries, slopes, agreement, target), ``scaling.md`` (tables)
and ``scaling.png`` (log-log time and memory per sweep with fitted slopes). ``--quick`` runs a small
version in well under a minute. The parts live in :mod:`studies.scaling_study`.

    pmht-opt study scaling --out studies/results/scaling
    python studies/scaling.py [--reps 3] [--backends banded kalman clarabel osqp] [--quick] [--fresh]
"""

from __future__ import annotations

import argparse
import concurrent.futures as cf
import dataclasses
import json
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from pmht_opt import available_backends
from pmht_opt.exceptions import ConfigError
from pmht_opt.mstep import BACKENDS
from studies.options import RunOptions, positive_int
from studies.provenance import load_average, provenance
from studies.report import write_json, write_text
from studies.scaling_study.design import FULL, GATES, QUICK, Design, params
from studies.scaling_study.markdown import markdown
from studies.scaling_study.measure import TABLE
from studies.scaling_study.plot import plot
from studies.scaling_study.summary import (
    agreement_rows,
    design_info,
    machine,
    scale_point,
    select,
    summarise_point,
    summarise_sweeps,
    target,
)
from studies.stored import run_provenance, stored_rows
from studies.trials import local_executor, run_trials

__all__ = ["TABLE", "Options", "main", "run", "verify_executor"]


def verify_executor() -> cf.Executor:
    """One worker, a new spawned process for every trial: how the study runs its trials."""
    return local_executor(1, max_tasks_per_child=1)


@dataclass(frozen=True)
class _Trials:
    """Runs batches of trials into one results file, each trial in a fresh child."""

    out_dir: Path
    progress: bool
    resume: bool
    tables_only: bool = False

    def __call__(self, trials: list[dict[str, Any]], label: str, first: bool = False) -> list[dict[str, Any]]:
        """Run ``trials`` under ``label``; only the first batch may start the file afresh (``--fresh``),
        later ones add to it. With ``tables_only``, the stored rows of ``trials`` instead."""
        if self.tables_only:
            return stored_rows(TABLE, trials, self.out_dir)
        ex = verify_executor()
        try:
            return run_trials(
                TABLE,
                trials,
                self.out_dir,
                executor=ex,
                progress=self.progress,
                label=label,
                resume=self.resume or not first,
            )
        finally:
            ex.shutdown(wait=True, cancel_futures=True)


def run(
    out_dir: Path,
    design: Design = FULL,
    backends: Sequence[str] = ("banded", "kalman", "clarabel", "osqp"),
    seed: int = 0,
    progress: bool = True,
    resume: bool = True,
    tables_only: bool = False,
) -> tuple[dict[str, Any], list[Path]]:
    """Run the study into ``out_dir``; return the summary written to ``scaling.json`` and the paths
    written. ``tables_only`` runs no plan: the summary comes from the rows already stored."""
    installed = set(available_backends())
    backends = [b for b in backends if b in installed]
    if not backends:
        raise ConfigError(f"backends: none installed; available: {', '.join(sorted(installed))}.")
    out_dir = Path(out_dir)
    it, reps, head = design.iterations, design.reps, design.headline
    load_start = load_average()
    measure = _Trials(out_dir, progress, resume, tables_only)

    rows = measure(
        [params("time", head, b, "auto", it, seed, 0) for b in backends], "scaling: backends", True
    )
    by_backend = {b: summarise_point(select(rows, solver=b)) for b in backends}
    timed = {b: s["wall_s"] for b, s in by_backend.items() if s["runs"]}
    if not timed:
        what = "has no stored plan" if tables_only else "failed"
        raise ConfigError(f"scaling: every backend {what} at the headline size; see scaling.jsonl.")
    fastest = min(timed, key=lambda b: timed[b])

    rows = measure(
        [params("time", head, fastest, g, it, seed, k) for g in GATES for k in range(reps)],
        "scaling: headline",
    )
    headline = {g: summarise_point(select(rows, gate=g)) for g in GATES}

    sweeps = design.sweep_points()
    points = list(dict.fromkeys(p for pts in sweeps.values() for p in pts))
    rows = measure(
        [params("time", p, fastest, g, it, seed, k) for p in points for g in GATES for k in range(reps)],
        "scaling: sweeps",
    )
    sweep_out = summarise_sweeps(rows, sweeps)

    sizes = dict.fromkeys([head, design.centre])
    rows = measure([params("agree", p, fastest, "both", it, seed, 0) for p in sizes], "scaling: agreement")
    agree = agreement_rows(rows)
    rows = measure([params("scale", design.scale, fastest, "auto", it, seed, 0)], "scaling: scale point")
    prov = provenance()
    summary: dict[str, Any] = {
        "design": design_info(design, seed),
        "machine": machine(prov, load_start),
        "provenance": prov,
        "backends": by_backend,
        "fastest": fastest,
        "headline": headline,
        "target": target(design, headline),
        "sweeps": sweep_out,
        "agreement": agree,
        "scale": scale_point(design, rows),
    }
    if tables_only:
        # Written from stored rows: the machine and provenance are those of the run that measured
        # them where its summary is still there (else this process's), and the runs are listed.
        stored = _stored_summary(out_dir)
        for key in ("machine", "provenance"):
            if isinstance(stored.get(key), dict):
                summary[key] = stored[key]
        summary["tables_only"] = True
        summary["runs"] = run_provenance(TABLE, out_dir)
        summary["written_by"] = prov
    return summary, _write(out_dir, summary, progress)


def _stored_summary(out_dir: Path) -> dict[str, Any]:
    """The ``scaling.json`` already in ``out_dir`` (empty if there is none or it cannot be read)."""
    try:
        data = json.loads((out_dir / "scaling.json").read_text())
    except (OSError, ValueError):
        return {}
    return data if isinstance(data, dict) else {}


def _write(out_dir: Path, summary: dict[str, Any], progress: bool) -> list[Path]:
    """``scaling.json``, ``scaling.md`` and ``scaling.png``; the paths written, the table first."""
    text = markdown(summary)
    written = [
        TABLE.path(out_dir),
        write_json(out_dir / "scaling.json", summary),
        write_text(out_dir / "scaling.md", text + "\n"),
        plot(summary, out_dir / "scaling.png"),
    ]
    if progress:
        print(text)
    return written


@dataclass(frozen=True)
class Options:
    """Options of ``pmht-opt study scaling``."""

    quick: bool = False
    reps: int | None = None
    iterations: int | None = None
    backends: tuple[str, ...] = ("banded", "kalman", "clarabel", "osqp")
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
            default=["banded", "kalman", "clarabel", "osqp"],
            choices=sorted(BACKENDS),
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
        tables_only=run_options.tables_only,
    )
    return written


if __name__ == "__main__":
    from studies.cli import run_script

    run_script("scaling", __file__)
