"""The ``pmht-opt`` command: a thin layer over the library.

Every subcommand turns its options into library calls: ``plan`` loads a mission file
(:func:`pmht_opt.io.load_mission`), overrides its planner settings with the options given, and runs it
with :func:`pmht_opt.io.plan_mission`; ``order`` runs :func:`pmht_opt.io.order_mission`. Outputs are
checked (format, directory, writable) before anything is planned.

Exit status: 0 done; 2 a bad input or a failed solve (``pmht-opt: error: ...``, one line, never a
traceback); 130 interrupted (Ctrl-C); 141 the reader of the output went away (``pmht-opt ... | head``),
as for a process ended by SIGPIPE.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import sys
import tempfile
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from pmht_opt.anneal import Anneal
from pmht_opt.exceptions import ConfigError, MissingDependencyError, PmhtOptError
from pmht_opt.io import (
    EXAMPLES,
    Mission,
    PlannerSettings,
    example_path,
    export_csv,
    export_geojson,
    export_qgc_plan,
    load_mission,
    order_mission,
    plan_mission,
    qgc_paths,
)
from pmht_opt.io.mission import DEFAULT_ALTITUDE
from pmht_opt.io.settings import ORDERINGS, PLANNERS
from pmht_opt.mstep import BACKENDS, available_backends
from pmht_opt.ordering import TourResult
from pmht_opt.result import PlanResult
from pmht_opt.scenario import paper_scenario

#: Exit statuses.
EXIT_ERROR, EXIT_INTERRUPTED, EXIT_PIPE = 2, 130, 141
#: Export formats by file suffix.
EXPORTS = {".csv": "CSV", ".geojson": "GeoJSON", ".plan": "QGroundControl plan"}
#: The library's planner defaults, shown in --help.
DEFAULTS = PlannerSettings()


class _Formatter(argparse.ArgumentDefaultsHelpFormatter):
    """Shows every default, except where there is none to show (``None``: the help says what
    happens instead)."""

    def _get_help_string(self, action: argparse.Action) -> str | None:
        if action.default is None or isinstance(action, argparse._StoreTrueAction):
            return action.help
        return super()._get_help_string(action)


def _fallback(key: str, value: Any) -> str:
    return f"(default: the mission's [planner] {key}, else {value})"


# ------------------------------------------------------------------ outputs


def _figure_formats() -> set[str]:
    from pmht_opt.plotting import figure_formats

    return figure_formats()


def check_output(option: str, path: Path, suffixes: set[str] | dict[str, str], what: str) -> Path:
    """Refuse, before anything is planned, an output path that cannot be written.

    Raises
    ------
    ConfigError
        An unknown format (the suffix), a directory, a parent that is a file, or a directory that
        refuses new files; the message names the option.
    """
    suffix = path.suffix.lower()
    if path.is_dir():
        raise ConfigError(f"{option}: {str(path)!r} is a directory; give a file name.")
    if suffix not in suffixes:
        known = ", ".join(sorted(suffixes))
        raise ConfigError(
            f"{option}: unknown {what} format {suffix or '(no suffix)'!r} of {str(path)!r}; use {known}."
        )
    parent = path.absolute().parent
    while not parent.exists():
        parent = parent.parent
    if not parent.is_dir():
        raise ConfigError(f"{option}: cannot write {str(path)!r}: {str(parent)!r} is not a directory.")
    try:
        with tempfile.TemporaryFile(dir=parent):
            pass
    except OSError as err:
        raise ConfigError(f"{option}: cannot write in {str(parent)!r}: {err.strerror or err}.") from None
    if path.exists() and not os.access(path, os.W_OK):
        raise ConfigError(f"{option}: {str(path)!r} exists and cannot be overwritten.")
    return path


def _prepare(path: Path) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    return path


@dataclass
class Outputs:
    """The files a planning command writes, checked up front."""

    figure: Path | None = None
    json: Path | None = None
    exports: list[Path] = field(default_factory=list)
    animation: Path | None = None

    @classmethod
    def of(cls, args: argparse.Namespace, mission: Mission | None, default_figure: Path | None) -> Outputs:
        out = cls()
        figure = getattr(args, "out", None) or default_figure
        if figure is not None:
            out.figure = check_output("--out", figure, _figure_formats(), "figure")
        if getattr(args, "json", None) is not None:
            out.json = check_output("--json", args.json, {".json"}, "metrics")
        for path in getattr(args, "export", None) or []:
            check_output("--export", path, EXPORTS, "export")
            if path.suffix.lower() == ".plan":
                if mission is None or mission.origin is None:
                    raise ConfigError(
                        f"--export {path}: a QGroundControl plan needs a geo-referenced mission "
                        "(a [geo] origin in the mission file)."
                    )
                for file in qgc_paths(path, mission.scenario.n_platforms):
                    check_output("--export", file, EXPORTS, "export")
            out.exports.append(path)
        if getattr(args, "animate", None) is not None:
            out.animation = check_output("--animate", args.animate, {".gif"}, "animation")
        return out


# ------------------------------------------------------------------ settings


def _add_planner_options(p: argparse.ArgumentParser, mission: bool) -> None:
    """Options of the EM planner; for a mission they override its ``[planner]`` table."""
    if mission:
        p.add_argument(
            "--planner", choices=PLANNERS, default=None, help=f"planner {_fallback('kind', DEFAULTS.kind)}"
        )
    say: Callable[[str, Any], str] = _fallback if mission else (lambda key, value: f"(default: {value})")
    p.add_argument(
        "--solver",
        default=None,
        choices=["auto", *sorted(BACKENDS)],
        help="M-step backend; auto: banded without constraints, clarabel with them "
        f"{say('solver', DEFAULTS.solver)}",
    )
    p.add_argument(
        "--iterations", type=int, default=None, help=f"EM iterations {say('iterations', DEFAULTS.iterations)}"
    )
    p.add_argument(
        "--tol",
        type=float,
        default=None,
        help=f"relative objective change to stop at, 0: never {say('tol', DEFAULTS.tol)}",
    )
    anneal = p.add_mutually_exclusive_group()
    anneal.add_argument(
        "--anneal",
        nargs=2,
        metavar=("START", "ITERATIONS"),
        default=None,
        help=f"anneal r geometrically from START over the first ITERATIONS iterations "
        f"{say('anneal', DEFAULTS.schedule().describe())}",
    )
    anneal.add_argument("--no-anneal", action="store_true", help="plain EM: the scenario's r from the start")
    p.add_argument(
        "--update-time-prior",
        action="store_true",
        default=None,
        help="re-estimate the time prior each iteration (the paper's literal setting)",
    )
    p.add_argument(
        "--paper", action="store_true", default=None, help="the paper's settings (PMHTConfig.paper())"
    )


def _add_output_options(p: argparse.ArgumentParser, default_figure: str | None) -> None:
    figure = f"(default: {default_figure})" if default_figure else "(default: none)"
    p.add_argument("--out", type=Path, default=None, help=f"write the figure here: PNG, PDF, SVG... {figure}")
    p.add_argument("--json", type=Path, default=None, help="write the metrics and paths here (default: none)")
    p.add_argument(
        "--export",
        type=Path,
        nargs="+",
        default=None,
        metavar="FILE",
        help="export the plan, the format by the suffix: .csv (one row per platform and step), .geojson, "
        ".plan (QGroundControl, one file per platform: NAME-0.plan, NAME-1.plan...; geo-referenced "
        "missions only)",
    )
    p.add_argument(
        "--animate", type=Path, default=None, help="write a GIF of the EM iterations here (default: none)"
    )
    p.add_argument("--show-radius", action="store_true", help="draw the coverage radius around each locale")
    p.add_argument("--quiet", action="store_true", help="no progress bar")


def _settings(args: argparse.Namespace, base: PlannerSettings) -> PlannerSettings:
    """``base`` with the options given on the command line."""
    changes: dict[str, Any] = {}
    for option, key in (
        ("planner", "kind"),
        ("solver", "solver"),
        ("iterations", "iterations"),
        ("tol", "tol"),
    ):
        value = getattr(args, option, None)
        if value is not None:
            changes[key] = value
    for option in ("update_time_prior", "paper", "return_to_base"):
        if getattr(args, option, None):
            changes[option] = True
    if getattr(args, "no_anneal", False):
        changes["anneal"] = Anneal(iterations=0)
    elif getattr(args, "anneal", None) is not None:
        try:
            start, iterations = float(args.anneal[0]), int(args.anneal[1])
        except ValueError:
            raise ConfigError(
                "--anneal: expected START (a number) and ITERATIONS (an integer), "
                f"got {' '.join(args.anneal)}."
            ) from None
        changes["anneal"] = Anneal(start=start, iterations=iterations)
    ordering = dict(base.ordering)
    method = getattr(args, "ordering", None) or getattr(args, "method", None)
    if method is not None and method != ordering["method"]:
        ordering = {"method": method}  # the file's options belong to its own method
    for option in ("seed", "time_limit", "min_tour", "ordering_iterations"):
        value = getattr(args, option, None)
        if value is not None:
            ordering["iterations" if option == "ordering_iterations" else option] = value
    if ordering != base.ordering:
        changes["ordering"] = ordering
    return base.replace(**changes) if changes else base


def _mission(args: argparse.Namespace) -> Mission:
    # A schedule given here replaces the file's: the file's is then not checked against its r.
    replaced = getattr(args, "no_anneal", False) or getattr(args, "anneal", None) is not None
    if getattr(args, "example", None) is not None:
        mission = load_mission(example_path(args.example), check_schedule=not replaced)
    elif args.mission is None:
        raise ConfigError("give a mission file, or --example NAME (pmht-opt example lists them).")
    else:
        mission = load_mission(args.mission, check_schedule=not replaced)
    settings = _settings(args, mission.planner)
    if settings is not mission.planner:
        try:
            settings.check_r(mission.scenario.r)
        except ConfigError as err:
            raise ConfigError(f"--anneal: {err}") from None
        mission.planner = settings
    if not mission.scenario.name and mission.source is not None:
        mission.scenario.name = mission.source.stem
    return mission


# ------------------------------------------------------------------ running


def _progress_bar(total: int, label: str, quiet: bool) -> Any:
    """A tqdm bar on stderr when tqdm is installed (the ``studies`` extra) and wanted; else ``None``."""
    if quiet:
        return None
    try:
        from tqdm import tqdm
    except ModuleNotFoundError:
        return None
    return tqdm(total=total, desc=label, file=sys.stderr)


def _plan(mission: Mission, outputs: Outputs, args: argparse.Namespace) -> PlanResult:
    s = mission.planner
    if mission.bounds_assumed:
        b = mission.scenario.bounds
        assert b is not None
        print(
            "bounds: none given; assumed the locales' bounding box "
            f"[{b[0]:.6g}, {b[1]:.6g}, {b[2]:.6g}, {b[3]:.6g}]"
        )
    snapshots = tuple(range(s.iterations + 1)) if outputs.animation is not None else ()
    label = {"pmht": "PMHT"}.get(s.kind, s.kind)
    bar = _progress_bar(s.iterations, f"{label} ({s.solver})", args.quiet)

    def progress(iteration: int, objective: float) -> None:
        if bar is not None:
            bar.set_postfix_str(f"objective {objective:.6g}", refresh=False)
            bar.update(1)

    try:
        result = plan_mission(mission, callback=progress, snapshots=snapshots)
    finally:
        if bar is not None:
            bar.close()
    _report(result, mission)
    _write(result, mission, outputs, args)
    return result


def _write(result: PlanResult, mission: Mission, outputs: Outputs, args: argparse.Namespace) -> None:
    from pmht_opt.plotting import plot_result

    unit = " (m)" if mission.origin is not None else ""
    if outputs.figure is not None:
        path = plot_result(result, _prepare(outputs.figure), show_radius=args.show_radius, unit=unit)
        print(f"figure: {path}")
    if outputs.animation is not None:
        from pmht_opt.animation import animate_plan

        print(f"animation: {animate_plan(result, _prepare(outputs.animation), unit=unit)}")
    if outputs.json is not None:
        payload = {
            "scenario": result.scenario.name,
            "metrics": result.metrics(),
            "positions": result.positions.tolist(),
            "assignment": result.assignment.tolist(),
            "visit_time": result.visit_time.tolist(),
        }
        _prepare(outputs.json).write_text(json.dumps(payload) + "\n")
        print(f"metrics and paths: {outputs.json}")
    for path in outputs.exports:
        suffix = path.suffix.lower()
        if suffix == ".csv":
            written = [export_csv(result, _prepare(path), mission.origin)]
        elif suffix == ".geojson":
            written = [export_geojson(result, _prepare(path), mission.origin)]
        else:
            assert mission.origin is not None
            written = export_qgc_plan(
                result,
                _prepare(path),
                mission.origin,
                altitude=args.altitude if args.altitude is not None else mission.altitude,
                speed=args.speed,
            )
        for file in written:
            print(f"{EXPORTS[suffix]}: {file}")


def _report(result: PlanResult, mission: Mission) -> None:
    m = result.metrics()
    h = result.history
    sc = result.scenario
    u = " m" if mission.origin is not None else ""
    rows = [
        ("scenario", sc.name or "-"),
        ("platforms / locales / horizon", f"{sc.n_platforms} / {sc.n_locales} / {sc.horizon} x {sc.dt:g} s"),
        ("planner", f"{mission.planner.kind}, solver {m['solver']}"),
        ("constraints", ", ".join(c.name for c in result.constraints) or "-"),
        ("iterations", f"{m['iterations']}" + (" (converged)" if m["converged"] else "")),
        ("annealing", m["anneal"]),
        ("total distance", f"{m['total_distance']:.2f}{u}"),
        (f"coverage within {m['coverage_radius']:g}{u}", f"{m['coverage']:.1%}"),
        ("mean / max miss distance", f"{m['mean_miss_distance']:.3f} / {m['max_miss_distance']:.3f}{u}"),
        ("locales per platform", " ".join(str(v) for v in m["locales_per_platform"])),
        ("crossings between platforms", str(m["crossings"])),
        (
            "max speed / acceleration (positions)",
            f"{m['max_speed']:.4g} / {m['max_acceleration']:.4g}",
        ),
        ("max excursion outside area", f"{m['max_excursion']:.3f}{u}"),
        ("max constraint violation", f"{result.max_violation:.1e}"),
        ("final EM objective", f"{m['final_objective']:.6g}"),
        (
            "wall time (E-step / M-step)",
            f"{m['wall_time']:.2f} s ({h.estep_time.sum():.2f} / {h.mstep_time.sum():.2f})",
        ),
    ]
    if mission.planner.return_to_base:
        gap = float(abs(result.positions[:, -1] - sc.start_positions).max())
        rows.insert(4, ("return to base", f"every platform ends within {gap:.1e}{u} of its start, at rest"))
    width = max(len(k) for k, _ in rows)
    for key, value in rows:
        print(f"{key:<{width}}  {value}")


# ------------------------------------------------------------------ commands


def _cmd_demo(args: argparse.Namespace) -> int:
    scenario = paper_scenario(args.scenario, seed=args.seed)
    mission = Mission(scenario)
    mission.planner = _settings(args, mission.planner)
    outputs = Outputs.of(args, mission, Path(f"pmht-demo-{args.scenario}.png"))
    _plan(mission, outputs, args)
    return 0


def _cmd_plan(args: argparse.Namespace) -> int:
    mission = _mission(args)
    outputs = Outputs.of(args, mission, None)
    _plan(mission, outputs, args)
    return 0


def _cmd_order(args: argparse.Namespace) -> int:
    mission = _mission(args)
    figure = check_output("--out", args.out, _figure_formats(), "figure") if args.out else None
    js = check_output("--json", args.json, {".json"}, "tour") if args.json else None
    tour: TourResult = order_mission(mission)
    sc = mission.scenario
    u = " m" if mission.origin is not None else ""
    print(f"ordering        {tour.method}" + (" (closed routes)" if mission.planner.return_to_base else ""))
    print(f"total distance  {tour.total_distance:.2f}{u}")
    print(f"wall time       {tour.wall_time:.2f} s")
    for m, route in enumerate(tour.routes):
        print(f"platform {m}      {len(route)} locales: {' '.join(str(int(n)) for n in route)}")
    if figure is not None:
        print(f"figure: {tour.plot(_prepare(figure), sc)}")
    if js is not None:
        _prepare(js).write_text(json.dumps(tour.to_dict()) + "\n")
        print(f"tour: {js}")
    return 0


def _cmd_example(args: argparse.Namespace) -> int:
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


def _cmd_scenario(args: argparse.Namespace) -> int:
    scenario = paper_scenario(args.kind, seed=args.seed)
    path = scenario.save(_prepare(check_output("--out", args.out, {".toml", ".json"}, "scenario")))
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


def _add_mission_source(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "mission", type=Path, nargs="?", default=None, help="mission or scenario file (.toml, .json)"
    )
    p.add_argument(
        "--example", choices=sorted(EXAMPLES), default=None, help="a built-in example mission instead"
    )
    p.add_argument(
        "--return-to-base",
        action="store_true",
        default=None,
        help="every platform ends at its start, at rest; orderings close their routes",
    )


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of ``pmht-opt``."""
    from pmht_opt import __version__

    parser = argparse.ArgumentParser(
        prog="pmht-opt",
        description="Multi-platform path planning with the PMHT and a QP M-step.",
        formatter_class=_Formatter,
    )
    parser.add_argument("--version", action="version", version=f"pmht-opt {__version__}")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    def command(name: str, help: str) -> argparse.ArgumentParser:
        return sub.add_parser(name, help=help, description=help, formatter_class=_Formatter)

    demo = command("demo", "plan one of the paper's scenarios, print the metrics, write a figure")
    demo.add_argument("--scenario", default="A", choices=["A", "B", "C"], help="the paper's scenario")
    demo.add_argument("--seed", type=int, default=0, help="scenario seed")
    _add_planner_options(demo, mission=False)
    _add_output_options(demo, "pmht-demo-SCENARIO.png")
    demo.set_defaults(func=_cmd_demo)

    plan = command("plan", "plan a mission file (or a built-in example) and write figures and exports")
    _add_mission_source(plan)
    _add_planner_options(plan, mission=True)
    plan.add_argument(
        "--ordering",
        choices=ORDERINGS,
        default=None,
        help=f"the smoothed planner's ordering {_fallback('ordering', DEFAULTS.method)}",
    )
    plan.add_argument(
        "--seed", type=int, default=None, help="the ordering's seed (ga, pyvrp) (default: the method's)"
    )
    _add_output_options(plan, None)
    plan.add_argument(
        "--altitude",
        type=float,
        default=None,
        help="flight altitude of .plan exports, m above take-off "
        f"(default: the mission's [geo] altitude, else {DEFAULT_ALTITUDE:g})",
    )
    plan.add_argument(
        "--speed",
        type=float,
        default=None,
        help="ground speed of .plan exports, m/s (default: each platform's mean planned speed)",
    )
    plan.set_defaults(func=_cmd_plan)

    order = command("order", "order the locales of a mission into one route per platform")
    _add_mission_source(order)
    order.add_argument(
        "--method",
        choices=ORDERINGS,
        default=None,
        help=f"ordering method {_fallback('ordering', DEFAULTS.method)}",
    )
    order.add_argument("--seed", type=int, default=None, help="seed (ga, pyvrp) (default: the method's)")
    order.add_argument(
        "--iterations",
        dest="ordering_iterations",
        type=int,
        default=None,
        help="iterations (ga, pyvrp) (default: the method's)",
    )
    order.add_argument(
        "--time-limit", type=float, default=None, help="seconds of search (ortools) (default: the method's)"
    )
    order.add_argument(
        "--min-tour", type=int, default=None, help="fewest locales per route (default: the method's)"
    )
    order.add_argument(
        "--out", type=Path, default=None, help="write a figure of the routes here (default: none)"
    )
    order.add_argument("--json", type=Path, default=None, help="write the routes here (default: none)")
    order.set_defaults(func=_cmd_order)

    example = command("example", "list the built-in example missions, print one, or copy its files")
    example.add_argument("name", nargs="?", choices=sorted(EXAMPLES), default=None, help="the example")
    example.add_argument(
        "--out", type=Path, default=None, help="copy the example's files into this directory"
    )
    example.set_defaults(func=_cmd_example)

    scen = command("scenario", "write one of the paper's scenarios to a file")
    scen.add_argument("kind", choices=["A", "B", "C"])
    scen.add_argument("--seed", type=int, default=0, help="scenario seed")
    scen.add_argument("--out", type=Path, required=True, help="file to write (.toml or .json)")
    scen.set_defaults(func=_cmd_scenario)

    solv = command("solvers", "list the M-step backends and whether they are installed")
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


def _silence_stdout() -> None:
    """Point stdout at /dev/null, so that the interpreter's last flush finds no closed pipe."""
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
    except (OSError, ValueError):
        pass


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point; returns the exit status (module notes)."""
    argv = list(sys.argv[1:] if argv is None else argv)
    try:
        if argv[:1] == ["study"]:
            return _cmd_study(argv[1:])
        try:
            args = build_parser().parse_args(argv)
        except SystemExit as exc:  # --help, --version, or argparse's own usage error (status 2)
            return exc.code if isinstance(exc.code, int) else EXIT_ERROR
        code: int = args.func(args)
        sys.stdout.flush()
    except PmhtOptError as err:
        print(f"pmht-opt: error: {err}", file=sys.stderr)
        return EXIT_ERROR
    except KeyboardInterrupt:
        print("pmht-opt: interrupted.", file=sys.stderr)
        return EXIT_INTERRUPTED
    except BrokenPipeError:
        _silence_stdout()
        return EXIT_PIPE
    except OSError as err:  # a file that vanished or a full disk between the checks and the writing
        name = f" {err.filename!r}" if err.filename else ""
        print(f"pmht-opt: error: cannot write{name}: {err.strerror or err}.", file=sys.stderr)
        return EXIT_ERROR
    return code


if __name__ == "__main__":
    sys.exit(main())
