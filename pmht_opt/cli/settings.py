"""The planner settings and the mission a command's options ask for.

A mission file states its own ``[planner]`` settings; the options given on the command line override
them one by one, so ``pmht-opt plan mission.toml --iterations 20`` changes the iterations and nothing
else. ``--planner`` switches the planner: the file's options of the planner it replaces are dropped
(they belong to that planner), while an option given on the command line that the chosen planner
does not take is refused, naming the flag.
"""

from __future__ import annotations

import argparse
from typing import Any

from pmht_opt.anneal import Anneal
from pmht_opt.exceptions import ConfigError
from pmht_opt.io import Mission, PlannerSettings, example_path, load_mission
from pmht_opt.planners import PLANNERS

#: Options that set a key of the mission's own: ``option -> key``.
MISSION = (("planner", "method"), ("iterations", "iterations"), ("tol", "tol"))
#: Switches that turn a mission key on.
SWITCHES = ("paper", "return_to_base")
#: Options that set a shared setting: ``option -> Settings field``.
SHARED = (("solver", "solver"), ("seed", "seed"))
#: Options that set one of the planner's own options: ``option -> {planner: option name}``.
OWN: dict[str, dict[str, str]] = {
    "radius": {"coverage": "radius", "smoothed": "visit_radius"},
    "ordering": {"smoothed": "orderer"},
    "update_time_prior": {"pmht": "update_time_prior"},
    "anneal": {"pmht": "anneal"},
    "objective": {"coverage": "objective", "smoothed": "objective"},
}


def planner_settings(args: argparse.Namespace, base: PlannerSettings) -> PlannerSettings:
    """``base`` with the options given on the command line (module notes)."""
    changes: dict[str, Any] = {}
    for option, key in MISSION:
        value = getattr(args, option, None)
        if value is not None:
            changes[key] = value
    for option in SWITCHES:
        if getattr(args, option, None):
            changes[option] = True
    method = changes.get("method", base.method)
    shared = dict(base.shared)
    for option, key in SHARED:
        value = getattr(args, option, None)
        if value is not None:
            shared[key] = value
    takes = set(PLANNERS[method].option_names())
    options = {k: v for k, v in base.options.items() if k in takes}
    for option, value in _own(args).items():
        name = OWN[option].get(method)
        if name is None:
            flag = "--" + option.replace("_", "-")
            owners = ", ".join(OWN[option])
            raise ConfigError(f"{flag}: an option of the {owners} planner, not of {method!r}.")
        options[name] = value
    if method != "pmht":  # the file's EM settings belong to the planner replaced
        for key, default in (("tol", 0.0), ("paper", False)):
            changes.setdefault(key, default)
    return base.replace(**changes, shared=shared, options=options)


def _own(args: argparse.Namespace) -> dict[str, Any]:
    """The planners' own options given on the command line, by option name."""
    out: dict[str, Any] = {}
    for option in ("radius", "ordering", "objective"):
        if getattr(args, option, None) is not None:
            out[option] = getattr(args, option)
    if getattr(args, "update_time_prior", None):
        out["update_time_prior"] = True
    anneal = _anneal(args)
    if anneal is not None:
        out["anneal"] = anneal
    return out


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
    if replaced:
        try:
            settings.check_r(mission.scenario.r)
        except ConfigError as err:
            raise ConfigError(f"--anneal: {err}") from None
    mission.planner = settings
    if not mission.scenario.name and mission.source is not None:
        mission.scenario.name = mission.source.stem
    return mission
