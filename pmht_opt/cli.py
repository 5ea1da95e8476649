"""The ``pmht-opt`` command: a thin layer over the library."""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from pmht_opt.anneal import Anneal
from pmht_opt.exceptions import ConfigError, MissingDependencyError, PmhtOptError
from pmht_opt.mstep import BACKENDS, available_backends
from pmht_opt.planner import PMHTConfig, plan_pmht
from pmht_opt.result import PlanResult
from pmht_opt.scenario import Scenario, paper_scenario


def _add_planner_options(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--solver",
        default="auto",
        choices=["auto", *sorted(BACKENDS)],
        help="M-step backend (default auto: banded without constraints, clarabel with them)",
    )
    p.add_argument("--iterations", type=int, default=100, help="maximum EM iterations (default 100)")
    p.add_argument("--tol", type=float, default=0.0, help="relative objective change to stop at (0: never)")
    p.add_argument(
        "--update-time-prior",
        action="store_true",
        help="re-estimate the time prior each iteration (the paper's literal setting)",
    )
    p.add_argument(
        "--anneal",
        nargs=2,
        metavar=("START", "ITERATIONS"),
        default=None,
        help="anneal r geometrically from START over the first ITERATIONS iterations (default 1.0 30)",
    )
    p.add_argument("--no-anneal", action="store_true", help="plain EM: the scenario's r from the start")
    p.add_argument("--paper", action="store_true", help="the paper's settings (PMHTConfig.paper())")
    p.add_argument("--out", type=Path, default=None, help="write the figure here (PNG, PDF, SVG)")
    p.add_argument("--json", type=Path, default=None, help="write the metrics and paths here")
    p.add_argument("--quiet", action="store_true", help="no progress bar")


def _config(args: argparse.Namespace) -> PMHTConfig:
    common: dict[str, Any] = {"solver": args.solver, "max_iter": args.iterations, "tol": args.tol}
    if args.no_anneal:
        common["anneal"] = None
    elif args.anneal is not None:
        try:
            start, iters = float(args.anneal[0]), int(args.anneal[1])
        except ValueError:
            raise ConfigError(
                f"--anneal: expected START (a number) and ITERATIONS (an integer), got {args.anneal}."
            ) from None
        common["anneal"] = Anneal(start=start, iterations=iters)
    if args.paper:
        return PMHTConfig.paper(**common)
    return PMHTConfig(update_time_prior=args.update_time_prior, **common)


def _progress_bar(total: int, label: str, quiet: bool) -> Any:
    """A tqdm bar on stderr when tqdm is installed (the ``studies`` extra) and wanted; else ``None``."""
    if quiet:
        return None
    try:
        from tqdm import tqdm
    except ModuleNotFoundError:
        return None
    return tqdm(total=total, desc=label, file=sys.stderr)


def _run(scenario: Scenario, args: argparse.Namespace, default_out: Path | None) -> PlanResult:
    cfg = _config(args)
    bar = _progress_bar(cfg.max_iter, f"PMHT ({cfg.solver})", args.quiet)

    def progress(it: int, objective: float) -> None:
        if bar is not None:
            bar.set_postfix_str(f"objective {objective:.6g}", refresh=False)
            bar.update(1)

    try:
        result = plan_pmht(scenario, cfg, callback=progress)
    finally:
        if bar is not None:
            bar.close()
    _report(result)
    out = args.out if args.out is not None else default_out
    if out is not None:
        print(f"figure: {result.plot(out)}")
    if args.json is not None:
        payload = {
            "scenario": scenario.name,
            "metrics": result.metrics(),
            "positions": result.positions.tolist(),
            "assignment": result.assignment.tolist(),
            "visit_time": result.visit_time.tolist(),
        }
        args.json.parent.mkdir(parents=True, exist_ok=True)  # as the figure's writer does
        args.json.write_text(json.dumps(payload) + "\n")
        print(f"metrics and paths: {args.json}")
    return result


def _report(result: PlanResult) -> None:
    m = result.metrics()
    h = result.history
    rows = [
        ("scenario", result.scenario.name or "-"),
        (
            "platforms / locales / horizon",
            f"{result.scenario.n_platforms} / {result.scenario.n_locales} / {result.scenario.horizon}",
        ),
        ("solver", m["solver"]),
        ("iterations", f"{m['iterations']}" + (" (converged)" if m["converged"] else "")),
        ("annealing", m["anneal"]),
        ("total distance", f"{m['total_distance']:.2f}"),
        (f"coverage within {m['coverage_radius']}", f"{m['coverage']:.1%}"),
        ("mean / max miss distance", f"{m['mean_miss_distance']:.3f} / {m['max_miss_distance']:.3f}"),
        ("locales per platform", " ".join(str(v) for v in m["locales_per_platform"])),
        ("crossings between platforms", str(m["crossings"])),
        ("max speed / acceleration", f"{m['max_speed']:.4f} / {m['max_acceleration']:.5f}"),
        ("max excursion outside area", f"{m['max_excursion']:.3f}"),
        ("final EM objective", f"{m['final_objective']:.6g}"),
        (
            "wall time (E-step / M-step)",
            f"{m['wall_time']:.2f} s ({h.estep_time.sum():.2f} / {h.mstep_time.sum():.2f})",
        ),
    ]
    width = max(len(k) for k, _ in rows)
    for key, value in rows:
        print(f"{key:<{width}}  {value}")


def _cmd_demo(args: argparse.Namespace) -> int:
    scenario = paper_scenario(args.scenario, seed=args.seed)
    _run(scenario, args, default_out=Path(f"pmht-demo-{args.scenario}.png"))
    return 0


def _cmd_plan(args: argparse.Namespace) -> int:
    scenario = Scenario.load(args.scenario_file)
    if not scenario.name:
        scenario.name = args.scenario_file.stem
    _run(scenario, args, default_out=None)
    return 0


def _cmd_scenario(args: argparse.Namespace) -> int:
    scenario = paper_scenario(args.kind, seed=args.seed)
    path = scenario.save(args.out)
    print(f"scenario {scenario.name}: {path}")
    return 0


def _cmd_solvers(args: argparse.Namespace) -> int:
    installed = set(available_backends())
    for name, backend in BACKENDS.items():
        hint = backend.spec.install_hint if backend.spec is not None else ""
        state = "available" if name in installed else f"missing ({hint})"
        print(f"{name:<9} {state}")
    return 0


def _cmd_study(argv: Sequence[str]) -> int:
    """``pmht-opt study ...``: forwarded to :mod:`studies.cli`, imported only now (the core never
    imports the studies)."""
    try:
        from studies.cli import main as study_main
    except ModuleNotFoundError as err:
        raise MissingDependencyError(
            f"the studies need {err.name}, which is not installed; "
            'install the extra: pip install ".[studies]"'
        ) from None
    return study_main(list(argv))


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of ``pmht-opt``."""
    parser = argparse.ArgumentParser(
        prog="pmht-opt", description="Multi-platform path planning with the PMHT and a QP M-step."
    )
    sub = parser.add_subparsers(dest="command", required=True)

    demo = sub.add_parser("demo", help="plan a built-in paper scenario, print metrics, write a figure")
    demo.add_argument("--scenario", default="A", choices=["A", "B", "C"], help="paper scenario (default A)")
    demo.add_argument("--seed", type=int, default=0, help="scenario seed (default 0)")
    _add_planner_options(demo)
    demo.set_defaults(func=_cmd_demo)

    plan = sub.add_parser("plan", help="plan a scenario file (.toml or .json)")
    plan.add_argument("scenario_file", type=Path)
    _add_planner_options(plan)
    plan.set_defaults(func=_cmd_plan)

    scen = sub.add_parser("scenario", help="write one of the paper's scenarios to a file")
    scen.add_argument("kind", choices=["A", "B", "C"])
    scen.add_argument("--seed", type=int, default=0)
    scen.add_argument("--out", type=Path, required=True, help="file to write (.toml or .json)")
    scen.set_defaults(func=_cmd_scenario)

    solv = sub.add_parser("solvers", help="list the M-step backends and whether they are installed")
    solv.set_defaults(func=_cmd_solvers)

    # Listed here for --help only: main() forwards ``study ...`` before parsing, so that the studies'
    # own parser (and its imports) is reached only when a study runs.
    study = sub.add_parser(
        "study",
        help="run a study (table1, anneal, solvers, scaling) into a directory; see pmht-opt study --help",
        add_help=False,
    )
    study.add_argument("args", nargs=argparse.REMAINDER)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point; returns the exit status (2 for a bad input or a failed solve, 130 interrupted)."""
    argv = list(sys.argv[1:] if argv is None else argv)
    try:
        if argv[:1] == ["study"]:
            return _cmd_study(argv[1:])
        args = build_parser().parse_args(argv)
        code: int = args.func(args)
    except PmhtOptError as err:
        print(f"pmht-opt: error: {err}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("pmht-opt: interrupted.", file=sys.stderr)
        return 130
    return code


if __name__ == "__main__":
    sys.exit(main())
