"""The files a command writes: checked before anything is planned, written after.

A run that is refused should be refused in milliseconds, not after minutes of planning: every output
path (figure, metrics, exports, animation) is checked for its format, its directory and whether it can
be written before the planner starts, and the writing afterwards only creates missing folders.
"""

from __future__ import annotations

import argparse
import json
import os
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from pmht_opt import validation
from pmht_opt.constraints import SpeedLimit
from pmht_opt.exceptions import ConfigError
from pmht_opt.io import Mission, export_csv, export_geojson, export_qgc_plan, qgc_paths
from pmht_opt.io.qgc import ENDS, SOURCES, PlanFiles
from pmht_opt.result import PlanResult
from pmht_opt.validation import writing

#: Export formats by file suffix.
EXPORTS = {".csv": "CSV", ".geojson": "GeoJSON", ".plan": "QGroundControl plan"}


def figure_formats() -> set[str]:
    """The suffixes matplotlib can write (imported only when a figure is asked for)."""
    from pmht_opt.plotting import figure_formats as formats

    return formats()


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


def write_text(path: Path, text: str) -> Path:
    """Write ``text`` to ``path`` whole or not at all (:func:`pmht_opt.validation.writing`)."""
    with writing(path) as part:
        part.write_text(text, encoding="utf-8")
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
        """The outputs the options ask for, each checked (:func:`check_output`)."""
        out = cls()
        figure = getattr(args, "out", None) or default_figure
        if figure is not None:
            out.figure = check_output("--out", figure, figure_formats(), "figure")
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
        _check_flight(args, any(p.suffix.lower() == ".plan" for p in out.exports), mission)
        return out

    def write(self, result: PlanResult, mission: Mission, args: argparse.Namespace) -> None:
        """Write every output of ``result``, printing each path."""
        from pmht_opt.plotting import plot_result

        unit = " (m)" if mission.origin is not None else ""
        if self.figure is not None:
            path = plot_result(result, self.figure, show_radius=args.show_radius, unit=unit)
            print(f"figure: {path}")
        if self.animation is not None:
            from pmht_opt.plotting.animation import animate_plan

            print(f"animation: {animate_plan(result, self.animation, unit=unit)}")
        if self.json is not None:
            payload = {
                "scenario": result.scenario.name,
                "metrics": result.metrics(),
                "positions": result.positions.tolist(),
                "assignment": result.assignment.tolist(),
                "visit_time": result.visit_time.tolist(),
            }
            write_text(self.json, json.dumps(payload) + "\n")
            print(f"metrics and paths: {self.json}")
        for path in self.exports:
            files = _export(result, mission, path, args)
            flights = files.flights if isinstance(files, PlanFiles) else ()
            for k, file in enumerate(files):
                print(f"{EXPORTS[path.suffix.lower()]}: {file}{_flight_text(flights[k]) if flights else ''}")


def _flight_text(flight: Any) -> str:
    """What a platform's exported flight is, in a few words (:class:`pmht_opt.io.qgc.Flight`)."""
    route = flight.route
    added = f", {route.added} added to keep the plan's promises" if route.added else ""
    return (
        f" ({len(route.waypoints)} waypoints{added}; {flight.speed:g} m/s; ends {flight.end}; legs within "
        f"{flight.deviation:.2f} m of the planned path)"
    )


def _check_flight(args: argparse.Namespace, plan_export: bool, mission: Mission | None) -> None:
    """The options of ``.plan`` exports checked before planning: ``--altitude`` and ``--speed``
    non-negative numbers, ``--end`` and ``--waypoints`` one of their choices (``tour`` only for the
    coverage planner, the one with a tour), and each only with a ``.plan`` export (the one output they
    change), so that none is silently ignored."""
    for flag, name in (
        ("--altitude", "altitude"),
        ("--speed", "speed"),
        ("--end", "end"),
        ("--waypoints", "waypoints"),
    ):
        value = getattr(args, name, None)
        if value is None:
            continue
        if name in ("end", "waypoints"):
            choices = ENDS if name == "end" else SOURCES
            if value not in choices:
                raise ConfigError(f"{flag}: expected one of {', '.join(choices)}, got {value!r}.")
        else:
            validation.real(flag, value, ConfigError, 0.0)
        if not plan_export:
            raise ConfigError(f"{flag}: applies to QGroundControl exports only; add --export FILE.plan.")
    speed = getattr(args, "speed", None)
    if mission is not None and speed is not None:
        for con in mission.constraints:
            if not isinstance(con, SpeedLimit) or con.soft:
                continue
            for m in con.applies_to(mission.scenario):
                limit = con.limit_for(m)
                if speed > limit:
                    raise ConfigError(
                        f"--speed: {speed:g} m/s is above platform {m}'s speed limit {limit:g} m/s, "
                        "which the plan keeps; give at most the limit, or leave --speed out to fly at it."
                    )
    method = mission.planner.method if mission is not None else "pmht"
    if getattr(args, "waypoints", None) == "tour" and method != "coverage":
        raise ConfigError(
            f"--waypoints tour: the {method} planner draws no straight-line tour; only the coverage "
            "planner does (--planner coverage), or export the plan's own waypoints (--waypoints plan)."
        )


def _export(result: PlanResult, mission: Mission, path: Path, args: argparse.Namespace) -> list[Path]:
    """Export ``result`` to ``path`` in the format its suffix names; the files written."""
    suffix = path.suffix.lower()
    if suffix == ".csv":
        return [export_csv(result, path, mission.origin)]
    if suffix == ".geojson":
        return [export_geojson(result, path, mission.origin)]
    assert mission.origin is not None
    return export_qgc_plan(
        result,
        path,
        mission.origin,
        altitude=args.altitude if args.altitude is not None else mission.altitude,
        speed=args.speed,
        end=args.end if args.end is not None else mission.end,
        source=args.waypoints or "plan",
    )
