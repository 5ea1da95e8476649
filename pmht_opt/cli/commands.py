"""The subcommands of ``pmht-opt``: each turns its parsed options into library calls.

Every command takes the parsed options and returns the exit status; errors are the library's own
(:class:`~pmht_opt.exceptions.PmhtOptError`), which :func:`pmht_opt.cli.main` reports in one line.
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import shutil
import sys
import tomllib
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from pmht_opt.cli.outputs import Outputs, check_output, figure_formats, write_text
from pmht_opt.cli.settings import mission_of, planner_settings
from pmht_opt.exceptions import ConfigError, MissingDependencyError
from pmht_opt.io import EXAMPLES, Mission, PlannerSettings, example_path, plan_mission
from pmht_opt.mstep import BACKENDS, available_backends
from pmht_opt.ordering import TourResult, order_locales
from pmht_opt.result import PlanResult
from pmht_opt.scenario import describe_radius, paper_scenario
from pmht_opt.stopping import Progress

#: Planners whose EM iterations ``--animate`` can show.
ANIMATED = ("pmht", "smoothed")
#: Iterations of each planner's run when the mission does not say (for the progress bar).
DEFAULT_ITERATIONS = {"pmht": 100, "smoothed": 100}
#: The planner of ``pmht-opt demo``.
DEMO_METHOD = "coverage"
#: The ``order`` command's options of the ordering: ``option -> option of the method``.
ORDER_OPTIONS = (
    ("seed", "seed"),
    ("time_limit", "time_limit"),
    ("min_tour", "min_tour"),
    ("ordering_iterations", "iterations"),
)


def _progress_bar(total: int | None, label: str, quiet: bool) -> Any:
    """A tqdm bar on stderr when tqdm is installed (the ``studies`` extra) and wanted; else ``None``."""
    if quiet:
        return None
    try:
        from tqdm import tqdm
    except ModuleNotFoundError:
        return None
    # No monitor thread: it only tunes how often a slow bar redraws, and a thread that takes the bar's
    # lock while Ctrl-C closes the bar is one more way for an interrupt to wait.
    tqdm.monitor_interval = 0
    return tqdm(total=total, desc=label, file=sys.stderr)


def plan(mission: Mission, outputs: Outputs, args: argparse.Namespace) -> PlanResult:
    """Plan ``mission`` with a progress bar, print its report and write its outputs."""
    s = mission.planner
    if mission.bounds_assumed:
        b = mission.scenario.bounds
        assert b is not None
        print(
            "bounds: none given; assumed the locales' bounding box "
            f"[{b[0]:.6g}, {b[1]:.6g}, {b[2]:.6g}, {b[3]:.6g}]"
        )
    if outputs.animation is not None and s.method not in ANIMATED:
        raise ConfigError(
            f"--animate: the {s.method} planner has no EM iterations to animate; it applies to "
            f"{' and '.join(ANIMATED)}."
        )
    total = s.iterations if s.iterations is not None else DEFAULT_ITERATIONS.get(s.method)
    snapshots = tuple(range(total + 1)) if outputs.animation is not None and total else ()
    # The coverage planner reports its tour search, which stops on its own (patience): no total, and
    # its iterations are not the flight's.
    bar_total = None if s.method not in DEFAULT_ITERATIONS else total
    solver = s.shared.get("solver", "auto")
    label = {"pmht": "PMHT"}.get(s.method, s.method)
    bar = _progress_bar(bar_total, f"{label} ({solver})", args.quiet)

    def progress(p: Progress) -> None:
        if bar is not None:
            score = p.scores[-1] if len(p.scores) else float("nan")
            # The EM reports the negative of its objective (lower is better); show the objective.
            text = f"objective {-score:.6g}" if p.stage == "em" else f"{p.stage} {score:.6g}"
            bar.set_postfix_str(text, refresh=False)
            bar.update(max(p.iteration - bar.n, 0))  # iterations done (the first report is at 0)

    try:
        result = plan_mission(mission, callback=progress, snapshots=snapshots)
    finally:
        if bar is not None:
            bar.close()
    report(result, mission)
    outputs.write(result, mission, args)
    return result


def report(result: PlanResult, mission: Mission) -> None:
    """Print the plan's metrics, one per line."""
    m = result.metrics()
    h = result.history
    sc = result.scenario
    u = " m" if mission.origin is not None else ""
    rows = [
        ("scenario", sc.name or "-"),
        ("platforms / locales / horizon", f"{sc.n_platforms} / {sc.n_locales} / {sc.horizon} x {sc.dt:g} s"),
        ("planner", f"{mission.planner.method}, solver {m['solver']}"),
        ("constraints", ", ".join(c.name for c in result.constraints) or "-"),
        ("iterations", f"{m['iterations']}" + (" (converged)" if m["converged"] else "")),
        ("annealing", m["anneal"]),
        ("total distance", f"{m['total_distance']:.2f}{u}"),
        ("mission time (last arrival)", f"{m['mission_time']:.1f} s" + _objective(result)),
        (f"coverage within {describe_radius(m['coverage_radius'])}{u}", f"{m['coverage']:.1%}"),
        ("mean / max miss distance", f"{m['mean_miss_distance']:.3f} / {m['max_miss_distance']:.3f}{u}"),
        ("locales per platform", " ".join(str(v) for v in m["locales_per_platform"])),
        ("crossings between platforms", str(m["crossings"])),
        (
            "max speed / acceleration (positions)",
            f"{m['max_speed']:.4g} / {m['max_acceleration']:.4g}",
        ),
        ("max excursion outside area", f"{m['max_excursion']:.3f}{u}"),
        ("max constraint violation", f"{result.max_violation:.1e}"),
    ]
    if result.planner == "coverage":  # no EM: a tour, then a flight of fixed weights
        rows.append(("straight-line tour", f"{float(result.extras['tour_length']):.2f}{u}"))
        rows.append(("wall time", f"{m['wall_time']:.2f} s"))
    else:
        rows.append(("final EM objective", f"{m['final_objective']:.6g}"))
        rows.append(
            (
                "wall time (E-step / M-step)",
                f"{m['wall_time']:.2f} s ({h.estep_time.sum():.2f} / {h.mstep_time.sum():.2f})",
            )
        )
    if mission.planner.return_to_base:
        gap = float(abs(result.positions[:, -1] - sc.start_positions).max())
        rows.insert(4, ("return to base", f"every platform ends within {gap:.1e}{u} of its start, at rest"))
    width = max(len(k) for k, _ in rows)
    for key, value in rows:
        print(f"{key:<{width}}  {value}")


def _objective(result: PlanResult) -> str:
    """`` (objective ...)`` for a plan whose planner chose its routes by an objective."""
    objective = result.extras.get("objective")
    return f" (routes for {objective})" if objective else ""


def demo(args: argparse.Namespace) -> int:
    """``pmht-opt demo``: one of the paper's scenarios."""
    scenario = paper_scenario(args.scenario, seed=args.seed)
    mission = Mission(scenario)
    mission.planner = planner_settings(args, PlannerSettings(method=DEMO_METHOD))
    outputs = Outputs.of(args, mission, Path(f"pmht-demo-{args.scenario}.png"))
    plan(mission, outputs, args)
    return 0


def plan_file(args: argparse.Namespace) -> int:
    """``pmht-opt plan``: a mission file or a built-in example."""
    mission = mission_of(args)
    outputs = Outputs.of(args, mission, None)
    plan(mission, outputs, args)
    return 0


def order(args: argparse.Namespace) -> int:
    """``pmht-opt order``: the routes of a mission's ordering."""
    mission = mission_of(args)
    figure = check_output("--out", args.out, figure_formats(), "figure") if args.out else None
    js = check_output("--json", args.json, {".json"}, "tour") if args.json else None
    tour: TourResult = _order(mission, args)
    sc = mission.scenario
    u = " m" if mission.origin is not None else ""
    print(f"ordering        {tour.method}" + (" (closed routes)" if mission.planner.return_to_base else ""))
    print(f"total distance  {tour.total_distance:.2f}{u}")
    print(f"wall time       {tour.wall_time:.2f} s")
    for m, route in enumerate(tour.routes):
        print(f"platform {m}      {len(route)} locales: {' '.join(str(int(n)) for n in route)}")
    if figure is not None:
        from pmht_opt.plotting import plot_tour

        print(f"figure: {plot_tour(tour, figure, sc, constraints=mission.constraints_for_plan())}")
    if js is not None:
        write_text(js, json.dumps(tour.to_dict()) + "\n")
        print(f"tour: {js}")
    return 0


def _order(mission: Mission, args: argparse.Namespace) -> TourResult:
    """The mission's ordering with the ``order`` command's options over the file's."""
    s = mission.planner
    method = args.method or s.options.get("orderer", "pyvrp")
    same = method == s.options.get("orderer", "pyvrp")
    options: dict[str, Any] = dict(s.options.get("order_options", {})) if same else {}
    if method in ("ga", "pyvrp") and "seed" in s.shared:
        options.setdefault("seed", s.shared["seed"])
    for option, key in ORDER_OPTIONS:
        value = getattr(args, option, None)
        if value is not None:
            options[key] = value
    if s.return_to_base:
        options["closed"] = True
    return order_locales(mission.scenario, method, **options)


def example(args: argparse.Namespace) -> int:
    """``pmht-opt example``: list, print or copy the built-in examples."""
    if args.name is None:
        for name, what in EXAMPLES.items():
            print(f"{name:<8} {what}")
        return 0
    source = example_path(args.name)
    if args.out is None:
        print(source.read_text(), end="")
        return 0
    if args.out.exists() and not args.out.is_dir():
        raise ConfigError(f"--out: {str(args.out)!r} is a file; give a directory.")
    args.out.mkdir(parents=True, exist_ok=True)
    for file in sorted(source.parent.glob(f"{args.name}*")):
        print(f"wrote: {shutil.copy(file, args.out / file.name)}")
    return 0


def scenario(args: argparse.Namespace) -> int:
    """``pmht-opt scenario``: one of the paper's scenarios to a file."""
    sc = paper_scenario(args.kind, seed=args.seed)
    path = sc.save(check_output("--out", args.out, {".toml", ".json"}, "scenario"))
    print(f"scenario {sc.name}: {path}")
    return 0


def solvers(args: argparse.Namespace) -> int:
    """``pmht-opt solvers``: the M-step backends and whether each is installed."""
    installed = set(available_backends())
    for name, backend in BACKENDS.items():
        hint = backend.spec.install_hint if backend.spec is not None else ""
        state = "available" if name in installed else f"missing ({hint})"
        print(f"{name:<9} {state}")
    return 0


def study_names() -> list[str]:
    """The studies ``pmht-opt study`` runs, read from their registry (``studies/registry.toml``)
    without importing them; empty where the studies are not installed or their registry is unreadable."""
    try:
        spec = importlib.util.find_spec("studies")  # finds the package; does not run it
        if spec is None or spec.origin is None:
            return []
        registry = Path(spec.origin).parent / "registry.toml"
        return list(tomllib.loads(registry.read_text()))
    except (ImportError, OSError, ValueError):
        return []


def study(argv: Sequence[str]) -> int:
    """``pmht-opt study ...``: forwarded to :mod:`studies.cli`, imported only now (the core never
    imports the studies)."""
    try:
        from studies.cli import main as study_main
    except ModuleNotFoundError as err:
        raise MissingDependencyError(
            f"the studies need {err.name}, which is not installed; "
            'install the extra: pip install ".[studies]"'
        ) from None
    import studies

    if getattr(studies, "__distribution__", None) != "pmht-opt":
        raise MissingDependencyError(
            f"the package 'studies' found at {getattr(studies, '__file__', '?')} is not pmht-opt's: "
            "another installed project uses the same top-level name; install pmht-opt into a virtual "
            "environment of its own."
        )
    return study_main(list(argv))
