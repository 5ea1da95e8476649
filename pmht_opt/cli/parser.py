"""The argument parser of ``pmht-opt``: one function per subcommand, sharing the groups of options.

Every ``--help`` shows the library's defaults; for a mission the planner options say that the mission's
own ``[planner]`` setting comes first.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable
from pathlib import Path
from typing import Any

from pmht_opt.cli import commands
from pmht_opt.io import EXAMPLES
from pmht_opt.io.mission import DEFAULT_ALTITUDE
from pmht_opt.io.settings import DEFAULT_METHOD
from pmht_opt.mstep import BACKENDS
from pmht_opt.ordering import METHODS as ORDERINGS
from pmht_opt.planners import PLANNERS

#: What ``add_subparsers`` returns (argparse names the class privately).
Subparsers = argparse._SubParsersAction


class _Formatter(argparse.ArgumentDefaultsHelpFormatter):
    """Shows every default, except where there is none to show (``None``: the help says what
    happens instead)."""

    def _get_help_string(self, action: argparse.Action) -> str | None:
        if action.default is None or isinstance(action, argparse._StoreTrueAction):
            return action.help
        return super()._get_help_string(action)


def _fallback(key: str, value: Any) -> str:
    return f"(default: the mission's [planner] {key}, else {value})"


def _add_planner_options(p: argparse.ArgumentParser, mission: bool) -> None:
    """Options of the EM planner; for a mission they override its ``[planner]`` table."""
    default = _fallback("method", DEFAULT_METHOD) if mission else f"(default: {commands.DEMO_METHOD})"
    p.add_argument("--planner", choices=list(PLANNERS), default=None, help=f"planner {default}")
    say: Callable[[str, Any], str] = _fallback if mission else (lambda key, value: f"(default: {value})")
    p.add_argument(
        "--solver",
        default=None,
        choices=["auto", *sorted(BACKENDS)],
        help=f"M-step backend; auto: banded without constraints, clarabel with them {say('solver', 'auto')}",
    )
    p.add_argument(
        "--iterations",
        type=int,
        default=None,
        help="iterations of the planner's run at most " + say("iterations", "the planner's own stop"),
    )
    p.add_argument(
        "--tol",
        type=float,
        default=None,
        help=f"pmht: relative objective change to stop at, 0: never {say('tol', 0)}",
    )
    anneal = p.add_mutually_exclusive_group()
    anneal.add_argument(
        "--anneal",
        nargs=2,
        metavar=("START", "ITERATIONS"),
        default=None,
        help="pmht: anneal r geometrically from START over the first ITERATIONS iterations "
        f"{say('anneal', 'geometric from 100 r over 30 iterations')}",
    )
    anneal.add_argument("--no-anneal", action="store_true", help="plain EM: the scenario's r from the start")
    p.add_argument(
        "--update-time-prior",
        action="store_true",
        default=None,
        help="pmht: re-estimate the time prior each iteration (the paper's literal setting)",
    )
    p.add_argument(
        "--paper", action="store_true", default=None, help="pmht: the paper's settings (PMHTOptions.paper())"
    )
    p.add_argument(
        "--radius",
        type=float,
        default=None,
        help="coverage: the sensor radius every locale must be within; smoothed: the visit radius "
        "(default: the mission's coverage_radius)",
    )
    p.add_argument(
        "--objective",
        choices=["distance", "time"],
        default=None,
        help="coverage, smoothed: the shortest routes in total (distance) or the earliest finish, the "
        "longest route as short as can be (time) (default: the mission's, else distance)",
    )
    if mission:  # demo's --seed is the scenario's
        p.add_argument(
            "--seed", type=int, default=None, help="seed of the planner's random choices (default: 0)"
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


def _command(sub: Subparsers[argparse.ArgumentParser], name: str, help: str) -> argparse.ArgumentParser:
    return sub.add_parser(name, help=help, description=help, formatter_class=_Formatter)


def _add_demo(sub: Subparsers[argparse.ArgumentParser]) -> None:
    demo = _command(sub, "demo", "plan one of the paper's scenarios, print the metrics, write a figure")
    demo.add_argument("--scenario", default="A", choices=["A", "B", "C"], help="the paper's scenario")
    demo.add_argument("--seed", type=int, default=0, help="scenario seed")
    _add_planner_options(demo, mission=False)
    _add_output_options(demo, "pmht-demo-SCENARIO.png")
    demo.set_defaults(func=commands.demo)


def _add_plan(sub: Subparsers[argparse.ArgumentParser]) -> None:
    plan = _command(sub, "plan", "plan a mission file (or a built-in example) and write figures and exports")
    _add_mission_source(plan)
    _add_planner_options(plan, mission=True)
    plan.add_argument(
        "--ordering",
        choices=sorted(ORDERINGS),
        default=None,
        help=f"the smoothed planner's ordering {_fallback('orderer', 'pyvrp')}",
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
        help="ground speed of .plan exports, m/s, at most the plan's speed limit (default: the plan's "
        "speed limit, else each platform's mean planned speed)",
    )
    plan.add_argument(
        "--end",
        default=None,
        metavar="{rtl,land,hover}",
        help="how .plan exports end: rtl (return to launch), land (at the last waypoint) or hover (hold "
        "at the last waypoint) (default: the mission's [geo] end, else land where a route ends at its "
        "start, rtl otherwise)",
    )
    plan.add_argument(
        "--waypoints",
        default=None,
        metavar="{plan,tour}",
        help="the waypoints of .plan exports: plan (points of the planned path, added to until every leg "
        "keeps the plan's promises) or tour (the coverage planner's straight-line tour) (default: plan)",
    )
    plan.set_defaults(func=commands.plan_file)


def _add_order(sub: Subparsers[argparse.ArgumentParser]) -> None:
    order = _command(sub, "order", "order the locales of a mission into one route per platform")
    _add_mission_source(order)
    order.add_argument(
        "--method",
        choices=sorted(ORDERINGS),
        default=None,
        help=f"ordering method {_fallback('orderer', 'pyvrp')}",
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
    order.set_defaults(func=commands.order)


def _add_files(sub: Subparsers[argparse.ArgumentParser]) -> None:
    """The commands that write or list files and backends, without planning."""
    example = _command(sub, "example", "list the built-in example missions, print one, or copy its files")
    example.add_argument("name", nargs="?", choices=sorted(EXAMPLES), default=None, help="the example")
    example.add_argument(
        "--out", type=Path, default=None, help="copy the example's files into this directory"
    )
    example.set_defaults(func=commands.example)

    scen = _command(sub, "scenario", "write one of the paper's scenarios to a file")
    scen.add_argument("kind", choices=["A", "B", "C"])
    scen.add_argument("--seed", type=int, default=0, help="scenario seed")
    scen.add_argument("--out", type=Path, required=True, help="file to write (.toml or .json)")
    scen.set_defaults(func=commands.scenario)

    solv = _command(sub, "solvers", "list the M-step backends and whether they are installed")
    solv.set_defaults(func=commands.solvers)


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
    _add_demo(sub)
    _add_plan(sub)
    _add_order(sub)
    _add_files(sub)
    # Listed here for --help only: main() forwards ``study ...`` before parsing, so that the studies'
    # own parser (and its imports) is reached only when a study runs.
    study = sub.add_parser(
        "study",
        help=f"run a study into a directory: {', '.join(commands.study_names()) or 'see'} "
        "(pmht-opt study --help)",
        add_help=False,
    )
    study.add_argument("args", nargs=argparse.REMAINDER)
    return parser
