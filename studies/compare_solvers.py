"""Study 2: the M-step backends against each other (``pmht-opt study solvers``).

Three parts, every backend (``kalman``, ``banded``, ``clarabel``, ``osqp``, and ``cvxpy`` with each
installed cvxpy solver) on the same problems:

Unconstrained single M-steps
    The E-step weights of a real EM run: the default (annealed) plan of paper scenarios A, B, C with
    the kalman M-step, stepped with :class:`pmht_opt.EMRun` to the M-steps of iterations ``K`` and
    ``K + 1``. Every backend solves iteration ``K`` first (so a warm-starting backend starts from the
    previous answer, as inside a plan) and iteration ``K + 1`` is timed; ``--repeats`` times, median
    reported. Two iterates: early (``K = 5``, annealed ``r``) and late (``K = 40``, the scenario's
    ``r``). Reference: the kalman (RTS) smoother.
Constrained single M-steps
    The late iterate with (a) a speed limit at 70% of the unconstrained answer's top speed plus area
    bounds, (b) a circular keep-out zone linearised at the iterate. The exact smoothers (kalman,
    banded) take no constraints; the reference is Clarabel at 1e-10 with iterative refinement. OSQP
    gets inner polygons for the cones, so its objective gap includes that approximation; the
    ``*_same`` columns compare it with the reference solve of the polygonal problem.
Whole plans
    ``--iterations`` (100) EM iterations on A, B, C, ``--seeds`` seeds (kalman, banded, clarabel, osqp)
    and ``--cvxpy-seeds`` seeds (each cvxpy solver): wall time, total distance and the largest position
    difference to the kalman plan of the same scenario, compared by statistics, not exactly
    (docs/model.md section 4.6): EM amplifies tiny M-step differences.

The QP backends run on one thread (``threads=1``) so the times compare the solvers, not the thread
pool. Every outcome is classified (:mod:`studies.solver_study.backends`): ``optimal``, ``inaccurate``
(single M-steps are solved with ``accept_inaccurate=True`` so the answer can still be measured; plans
are not), ``infeasible``, ``failed``, or ``n/a`` (the solver cannot take the problem class, e.g. an
LP-only cvxpy solver). Solver options are the library's defaults (:mod:`pmht_opt.mstep.tuning`), and
cvxpy's defaults for cvxpy solvers other than CLARABEL.

Outputs in ``--out``: ``solvers_msteps.jsonl`` (one row per M-step and backend, written whole at the
end of a run), ``solvers_plans.jsonl`` (one row per plan; resumable, ``--fresh`` starts it afresh),
``solvers.json`` (settings, provenance, summaries), ``solvers.md`` (the tables) and ``solvers.png``
(time against position difference). The parts live in :mod:`studies.solver_study`.

    pmht-opt study solvers --out studies/results/solvers
    python studies/compare_solvers.py [--quick] [--fresh]
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from pmht_opt.exceptions import ConfigError
from studies.options import RunOptions, positive_int
from studies.provenance import load_average, provenance
from studies.report import write_json, write_text
from studies.solver_study.backends import (
    ACCEPT,
    PLAN_VARIANTS,
    QUICK_SKIP,
    backends,
    cvxpy_solvers,
)
from studies.solver_study.iterates import (
    CONSTRAINED_CASES,
    QUICK_STAGES,
    STAGES,
    make_iterate,
    study_scenario,
)
from studies.solver_study.markdown import markdown
from studies.solver_study.msteps import (
    MSTEPS,
    MSTEPS_NAME,
    REFERENCE_SETTINGS,
    constrained_jobs,
    constrained_rows,
    unconstrained_rows,
    write_msteps,
)
from studies.solver_study.plans import PLANS
from studies.solver_study.plot import plot
from studies.solver_study.summary import summarise_msteps, summarise_plans
from studies.store import read_rows
from studies.stored import run_provenance
from studies.trials import run_trials

#: The study's trial table, for ``--verify``.
TABLE = PLANS
PARTS = ("unconstrained", "constrained", "plans")

Rows = Sequence[Mapping[str, Any]]

__all__ = ["MSTEPS", "PLANS", "TABLE", "Options", "main", "run"]


def measure_msteps(
    kinds: Sequence[str],
    seed: int,
    stages: Mapping[str, int],
    labels: Sequence[str],
    repeats: int,
    horizon: int,
    parts: Sequence[str],
    progress: bool,
) -> list[dict[str, Any]]:
    """The single M-step rows of the parts asked for, every backend on every scenario."""
    n_units = 0
    if "unconstrained" in parts:
        n_units += len(kinds) * len(stages) * len(labels)
    if "constrained" in parts:
        n_units += len(kinds) * len(CONSTRAINED_CASES) * (1 + len(constrained_jobs(labels)))
    from tqdm import tqdm

    bar = tqdm(total=n_units, desc="solvers: M-steps", disable=not (progress and n_units), file=sys.stderr)
    rows: list[dict[str, Any]] = []
    try:
        for kind in kinds:
            sc = study_scenario(kind, seed, horizon)
            iterates = {name: make_iterate(sc, k) for name, k in stages.items()}
            if "unconstrained" in parts:
                for name, it in iterates.items():
                    rows += unconstrained_rows(it, name, seed, labels, repeats, bar)
            if "constrained" in parts:
                late = iterates[list(stages)[-1]]
                for case in CONSTRAINED_CASES:
                    rows += constrained_rows(late, case, seed, labels, repeats, bar)
    finally:
        bar.close()
    for r in rows:
        r["group"] = r["case"].split("-")[-1] if r["part"] == "unconstrained" else r["case"]
    return rows


def plan_params(
    kinds: Sequence[str], labels: Sequence[str], seeds: int, cvxpy_seeds: int, iterations: int, horizon: int
) -> list[dict[str, Any]]:
    """The whole-plan trials: each backend (and its variants) on each scenario and seed, seed-major so
    the kalman plan of a scenario comes before the others that compare with it."""
    plan_labels: list[str] = []
    for label in labels:
        plan_labels.append(label)
        plan_labels += [v for v in PLAN_VARIANTS if v.removesuffix(ACCEPT) == label]
    trials = []
    for kind in kinds:
        for seed in range(max(seeds, cvxpy_seeds)):
            for label in plan_labels:
                if seed >= (cvxpy_seeds if label.startswith("cvxpy/") else seeds):
                    continue
                trials.append(
                    {
                        "kind": kind,
                        "seed": seed,
                        "backend": label,
                        "iterations": iterations,
                        "horizon": horizon,
                    }
                )
    return trials


def run(
    out_dir: Path,
    *,
    kinds: Sequence[str] = ("A", "B", "C"),
    mstep_seed: int = 0,
    stages: Mapping[str, int] | None = None,
    repeats: int = 5,
    seeds: int = 5,
    cvxpy_seeds: int = 2,
    iterations: int = 100,
    horizon: int = 500,
    parts: Sequence[str] = PARTS,
    cvxpy_names: Sequence[str] | None = None,
    executor: Any = None,
    progress: bool = True,
    resume: bool = True,
    command: str = "pmht-opt study solvers",
    tables_only: bool = False,
) -> tuple[dict[str, Any], list[Path]]:
    """Run the study into ``out_dir``; return the summaries (also written to ``solvers.json``) and the
    paths written.

    ``tables_only`` rewrites the summaries, tables and figure from the raw tables already in
    ``out_dir`` (and the settings in its ``solvers.json``) without measuring anything.
    """
    out_dir = Path(out_dir)
    if tables_only:
        return _report(out_dir, progress)
    load_start = load_average()
    stages = dict(STAGES if stages is None else stages)
    names = cvxpy_solvers() if cvxpy_names is None else [str(s).upper() for s in cvxpy_names]
    labels = backends(names)
    mstep_rows = measure_msteps(kinds, mstep_seed, stages, labels, repeats, horizon, parts, progress)
    written: list[Path] = []
    if mstep_rows:
        written.append(write_msteps(out_dir / f"{MSTEPS_NAME}.jsonl", mstep_rows))
    plan_rows: list[dict[str, Any]] = []
    if "plans" in parts:
        trials = plan_params(kinds, labels, seeds, cvxpy_seeds, iterations, horizon)
        plan_rows = run_trials(
            PLANS,
            trials,
            out_dir,
            executor=executor,
            progress=progress,
            label="solvers: plans",
            resume=resume,
        )
        written.append(PLANS.path(out_dir))
    settings = {
        "kinds": list(kinds),
        "mstep_seed": mstep_seed,
        "stages": stages,
        "repeats": repeats,
        "seeds": seeds,
        "cvxpy_seeds": cvxpy_seeds,
        "iterations": iterations,
        "horizon": horizon,
        "parts": list(parts),
        "backends": labels,
        "reference_settings": REFERENCE_SETTINGS,
        "load_average": f"{load_start} at the start, {load_average()} at the end",
        "command": command,
    }
    summary, files = _write(out_dir, settings, mstep_rows, plan_rows, progress)
    return summary, written + files


def _write(
    out_dir: Path,
    settings: Mapping[str, Any],
    mstep_rows: Rows,
    plan_rows: Rows,
    progress: bool,
    measured: Mapping[str, Any] | None = None,
) -> tuple[dict[str, Any], list[Path]]:
    """Summaries, ``solvers.json``, ``solvers.md`` and ``solvers.png`` from the raw rows; the same
    function serves a run and ``--tables-only``, so both write the same text from the same rows.
    ``measured`` is the provenance of the run that measured the rows (``--tables-only``: the one
    stored); by default this process's."""
    mstep_summary = summarise_msteps(mstep_rows)
    plan_summary = summarise_plans(plan_rows)
    prov = dict(measured) if measured is not None else provenance()
    summary: dict[str, Any] = {
        "settings": dict(settings),
        "provenance": prov,
        "msteps": mstep_summary,
        "plans": plan_summary,
    }
    if measured is not None:
        summary["tables_only"] = True
        summary["runs"] = run_provenance(PLANS, out_dir) if PLANS.path(out_dir).exists() else []
        summary["written_by"] = provenance()
    text = markdown(mstep_summary, plan_summary, plan_rows, settings, prov)
    files = [
        write_json(out_dir / "solvers.json", summary),
        write_text(out_dir / "solvers.md", text),
        plot(mstep_rows, plan_rows, out_dir / "solvers.png"),
    ]
    if progress:
        print(text)
    return summary, files


def _report(out_dir: Path, progress: bool) -> tuple[dict[str, Any], list[Path]]:
    """Summaries, tables and figure again from the raw tables and settings already in ``out_dir``."""
    try:
        stored = json.loads((out_dir / "solvers.json").read_text())
        settings, measured = stored["settings"], stored["provenance"]
    except (OSError, ValueError, KeyError, TypeError) as err:
        raise ConfigError(f"--tables-only: no usable {out_dir / 'solvers.json'} ({err}).") from None
    parts = settings["parts"]
    mstep_rows: list[dict[str, Any]] = []
    if "unconstrained" in parts or "constrained" in parts:
        mstep_rows = read_rows(out_dir / f"{MSTEPS_NAME}.jsonl", MSTEPS, MSTEPS_NAME)
    plan_rows = []
    if "plans" in parts:
        # The table may hold rows of other runs (other seeds, horizons): keep this run's.
        backends_run = {*settings["backends"], *PLAN_VARIANTS}
        for r in read_rows(PLANS.path(out_dir), PLANS.schema, PLANS.name):
            seeds = settings["cvxpy_seeds"] if r["backend"].startswith("cvxpy/") else settings["seeds"]
            if (
                r["kind"] in settings["kinds"]
                and r["backend"] in backends_run
                and r["seed"] < seeds
                and r["iterations"] == settings["iterations"]
                and r["horizon"] == settings["horizon"]
            ):
                plan_rows.append(r)
    return _write(out_dir, settings, mstep_rows, plan_rows, progress, measured)


@dataclass(frozen=True)
class Options:
    """Options of ``pmht-opt study solvers``; ``quick`` is a reduced run (scenario A, short horizon)."""

    quick: bool = False
    kinds: tuple[str, ...] = ("A", "B", "C")
    repeats: int = 5
    seeds: int = 5
    cvxpy_seeds: int = 2
    iterations: int = 100
    horizon: int = 500
    parts: tuple[str, ...] = PARTS
    cvxpy_solvers: tuple[str, ...] | None = None

    def __post_init__(self) -> None:
        positive_int("--repeats", self.repeats)
        positive_int("--seeds", self.seeds)
        positive_int("--cvxpy-seeds", self.cvxpy_seeds, minimum=0)
        positive_int("--iterations", self.iterations)
        positive_int("--horizon", self.horizon, minimum=2)
        if not self.kinds or not self.parts:
            raise ConfigError("--kinds and --parts: expected at least one value each.")

    def command(self) -> str:
        """The command that reproduces a run with these options: ``--quick`` if set, then every option
        that differs from the defaults of that mode (full or quick), and the cvxpy solvers if named."""
        words = ["pmht-opt study solvers"] + (["--quick"] if self.quick else [])
        base = QUICK_OPTIONS if self.quick else Options()
        for flag, value, default in (
            ("--kinds", self.kinds, base.kinds),
            ("--repeats", self.repeats, base.repeats),
            ("--seeds", self.seeds, base.seeds),
            ("--cvxpy-seeds", self.cvxpy_seeds, base.cvxpy_seeds),
            ("--iterations", self.iterations, base.iterations),
            ("--horizon", self.horizon, base.horizon),
            ("--parts", self.parts, base.parts),
        ):
            if value != default:
                words.append(f"{flag} {' '.join(map(str, value)) if isinstance(value, tuple) else value}")
        if self.cvxpy_solvers is not None:
            words.append("--cvxpy-solvers " + " ".join(self.cvxpy_solvers))
        return " ".join(words)

    @staticmethod
    def add_arguments(p: argparse.ArgumentParser) -> None:
        """The command-line options of this study."""
        p.add_argument("--quick", action="store_true", help="a reduced run (scenario A, short horizon)")
        p.add_argument("--kinds", nargs="+", default=None, choices=["A", "B", "C"], help="paper scenarios")
        p.add_argument("--repeats", type=int, default=None, help="timed solves per M-step (default 5)")
        p.add_argument(
            "--seeds", type=int, default=None, help="plan seeds for kalman/clarabel/osqp (default 5)"
        )
        p.add_argument(
            "--cvxpy-seeds", type=int, default=None, help="plan seeds per cvxpy solver (default 2)"
        )
        p.add_argument("--iterations", type=int, default=None, help="EM iterations per plan (default 100)")
        p.add_argument("--horizon", type=int, default=None, help="time steps (default: the paper's 500)")
        p.add_argument(
            "--parts", nargs="+", default=list(PARTS), choices=list(PARTS), help="which parts to run"
        )
        p.add_argument(
            "--cvxpy-solvers", nargs="+", default=None, help="cvxpy solvers (default: all installed)"
        )

    @classmethod
    def from_args(cls, ns: argparse.Namespace) -> Options:
        """The options from parsed arguments; ``--quick`` changes the defaults of those not given."""
        quick = bool(ns.quick)

        def pick(value: int | None, full: int, reduced: int) -> int:
            return value if value is not None else (reduced if quick else full)

        names = ns.cvxpy_solvers
        if names is None and quick:
            names = [n for n in cvxpy_solvers() if n not in QUICK_SKIP]
        full, reduced = Options(), QUICK_OPTIONS
        return cls(
            quick=quick,
            kinds=tuple(ns.kinds) if ns.kinds else (reduced.kinds if quick else full.kinds),
            repeats=pick(ns.repeats, full.repeats, reduced.repeats),
            seeds=pick(ns.seeds, full.seeds, reduced.seeds),
            cvxpy_seeds=pick(ns.cvxpy_seeds, full.cvxpy_seeds, reduced.cvxpy_seeds),
            iterations=pick(ns.iterations, full.iterations, reduced.iterations),
            horizon=pick(ns.horizon, full.horizon, reduced.horizon),
            parts=tuple(ns.parts),
            cvxpy_solvers=None if names is None else tuple(names),
        )


#: The defaults of ``--quick`` (cvxpy solvers aside): what :meth:`Options.command` compares with.
QUICK_OPTIONS = Options(
    quick=True, kinds=("A",), repeats=2, seeds=1, cvxpy_seeds=1, iterations=10, horizon=80
)


def main(run_options: RunOptions, options: Options) -> list[Path]:
    """``pmht-opt study solvers``: return the paths written."""
    out = run_options.prepare()
    with run_options.executor() as ex:
        _, written = run(
            out,
            kinds=options.kinds,
            stages=QUICK_STAGES if options.quick else STAGES,
            repeats=options.repeats,
            seeds=options.seeds,
            cvxpy_seeds=options.cvxpy_seeds,
            iterations=options.iterations,
            horizon=options.horizon,
            parts=options.parts,
            cvxpy_names=options.cvxpy_solvers,
            executor=ex,
            progress=not run_options.quiet,
            resume=not run_options.fresh,
            command=options.command(),
            tables_only=run_options.tables_only,
        )
    return written


if __name__ == "__main__":
    from studies.cli import run_script

    run_script("solvers", __file__)
