"""The planner settings and the mission a command's options ask for.

A mission file states its own ``[planner]`` settings; the options given on the command line override
them one by one, so ``pmht-opt plan mission.toml --iterations 20`` changes the iterations and nothing
else.
"""

from __future__ import annotations

import argparse
from typing import Any

from pmht_opt.anneal import Anneal
from pmht_opt.exceptions import ConfigError
from pmht_opt.io import Mission, PlannerSettings, example_path, load_mission

#: The options that replace a setting of the same meaning: ``option -> setting``.
REPLACED = (("planner", "kind"), ("solver", "solver"), ("iterations", "iterations"), ("tol", "tol"))
#: The switches that turn a setting on.
SWITCHES = ("update_time_prior", "paper", "return_to_base")
#: The options of the ordering: ``option -> key of PlannerSettings.ordering``.
ORDERING = (
    ("seed", "seed"),
    ("time_limit", "time_limit"),
    ("min_tour", "min_tour"),
    ("ordering_iterations", "iterations"),
)


def planner_settings(args: argparse.Namespace, base: PlannerSettings) -> PlannerSettings:
    """``base`` with the options given on the command line."""
    changes: dict[str, Any] = {}
    for option, key in REPLACED:
        value = getattr(args, option, None)
        if value is not None:
            changes[key] = value
    for option in SWITCHES:
        if getattr(args, option, None):
            changes[option] = True
    anneal = _anneal(args)
    if anneal is not None:
        changes["anneal"] = anneal
    ordering = _ordering(args, base.ordering)
    if ordering != base.ordering:
        changes["ordering"] = ordering
    return base.replace(**changes) if changes else base


def _anneal(args: argparse.Namespace) -> Anneal | None:
    """The schedule ``--no-anneal`` or ``--anneal START ITERATIONS`` asks for, if either was given."""
    if getattr(args, "no_anneal", False):
        return Anneal(iterations=0)
    if getattr(args, "anneal", None) is None:
        return None
    try:
        start, iterations = float(args.anneal[0]), int(args.anneal[1])
    except ValueError:
        raise ConfigError(
            f"--anneal: expected START (a number) and ITERATIONS (an integer), got {' '.join(args.anneal)}."
        ) from None
    return Anneal(start=start, iterations=iterations)


def _ordering(args: argparse.Namespace, base: dict[str, Any]) -> dict[str, Any]:
    """The ordering's settings: ``base`` with the method and its options given on the command line."""
    ordering = dict(base)
    method = getattr(args, "ordering", None) or getattr(args, "method", None)
    if method is not None and method != ordering["method"]:
        ordering = {"method": method}  # the file's options belong to its own method
    for option, key in ORDERING:
        value = getattr(args, option, None)
        if value is not None:
            ordering[key] = value
    return ordering


def mission_of(args: argparse.Namespace) -> Mission:
    """The mission file (or built-in example) the options name, with their settings applied."""
    # A schedule given here replaces the file's: the file's is then not checked against its r.
    replaced = getattr(args, "no_anneal", False) or getattr(args, "anneal", None) is not None
    if getattr(args, "example", None) is not None and args.mission is not None:
        raise ConfigError(f"give a mission file or --example NAME, not both (got {args.mission} too).")
    if getattr(args, "example", None) is not None:
        mission = load_mission(example_path(args.example), check_schedule=not replaced)
    elif args.mission is None:
        raise ConfigError("give a mission file, or --example NAME (pmht-opt example lists them).")
    else:
        mission = load_mission(args.mission, check_schedule=not replaced)
    settings = planner_settings(args, mission.planner)
    if hasattr(args, "ordering") and settings.kind != "smoothed":  # `plan`: the ordering's options
        given = [f"--{option}" for option in ("ordering", "seed") if getattr(args, option, None) is not None]
        if given:
            raise ConfigError(
                f"{given[0]}: the {settings.kind} planner runs no ordering; "
                "it applies with --planner smoothed."
            )
    if settings is not mission.planner:
        try:
            settings.check_r(mission.scenario.r)
        except ConfigError as err:
            raise ConfigError(f"--anneal: {err}") from None
        mission.planner = settings
    if not mission.scenario.name and mission.source is not None:
        mission.scenario.name = mission.source.stem
    return mission
