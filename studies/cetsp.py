"""Study: the coverage planner on the Close-Enough TSP benchmark, against the best published tours.

The single-vehicle, closed-tour case of full coverage at a radius is the Close-Enough TSP (CETSP);
W. Mennell's instances (2009) are its standard benchmark, with best-known solutions (BKS) published by
the state of the art (``studies/benchmarks/cetsp/README.md`` gives every file's source). Each trial
plans one case with ``pmht_opt.plan(scenario, "coverage")``: the depot is the single start, every
target has its own radius, the route returns to base (``Terminal.return_to_base()``), and every other
setting is the planner's default (the planner's ``seed`` is the trial's). It records:

- ``straight``: the length of the planner's straight-line tour (``result.extras["tour"]``, measured
  here on its vertices), and ``straight_ratio`` = straight / BKS (a BKS is a straight-line tour too);
- ``smooth``: the length of the smooth path (the segments between consecutive positions), and
  ``smooth_ratio`` = smooth / BKS;
- coverage checked by this study on the *segments* of both (:mod:`studies.segment_coverage`, none of
  the library's geometry): ``straight_gap`` and ``smooth_gap``, the worst target's (distance - radius) /
  radius (covered up to 1e-6), and the fraction covered;
- how far each route's ends are from the depot, the tour engine's stages (length after the centres'
  order, the cone program, the descent and the search), its iterations, and the seconds (wall, CPU,
  and until the tour search's last iteration).

Invariance rows (the first seed): the same case at other horizons T (default 500, 1000, 2000) and with
coordinates and radii scaled (default by 0.01, 1, 100; the lengths are scaled back before they are
recorded). A length must not depend on the units, nor much on T.

Cases come from tables (``--tables``): ``development`` (the 16 cases of the development subset),
``extra`` (larger instances, never used to tune the planner), or the path of a CSV of your own with
the columns ``name``, ``file`` (a Mennell-format file, :func:`pmht_opt.tours.read_mennell`, relative
to the CSV), ``radius_factor`` and optionally ``bks`` and ``bks_source``.

    pmht-opt study cetsp --out studies/results/cetsp                   # development cases, seeds 0 1 2
    pmht-opt study cetsp --tables development extra --out studies/results/cetsp
    pmht-opt study cetsp --quick --out /tmp/cetsp                      # seconds: two small cases

The summary (``cetsp_summary.json``, ``cetsp.md``) gives per table: per case the ratios of every seed,
the spread of the seeds (worst / best - 1), the largest times, coverage and the invariance spreads;
over the cases the mean and largest ratios; and the targets of the benchmark, each met or not.
"""

from __future__ import annotations

import csv
import functools
import math
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from pmht_opt import Scenario, Settings, Terminal, plan
from pmht_opt.exceptions import ConfigError
from pmht_opt.tours import read_mennell
from studies.options import Count, Flag, Integers, Positives, RunOptions, StudyOptions, Texts, Without, option
from studies.segment_coverage import RTOL, covered_fraction, relative_gaps
from studies.trials import TIME_CHECKS, TIME_COLUMNS, Check, TrialTable

#: The benchmark's files, shipped with the studies (package data).
BENCHMARKS = Path(__file__).resolve().parent / "benchmarks" / "cetsp"
#: The tables of cases shipped with the studies, by name.
TABLES = {"development": BENCHMARKS / "development.csv", "extra": BENCHMARKS / "extra.csv"}
SEEDS = (0, 1, 2)
HORIZON = 1000
INVARIANCE_HORIZONS = (500, 1000, 2000)
INVARIANCE_SCALES = (0.01, 1.0, 100.0)
#: ``--quick``: a run of seconds (the cases default to the two with the fewest targets).
QUICK = {"seeds": (0,), "horizon": 200, "invariance_horizons": (100, 200, 400)}
#: The targets of the benchmark (a ratio is a length over the best published tour).
TARGETS = {
    "mean_straight_ratio": 1.01,
    "max_straight_ratio": 1.03,
    "mean_smooth_ratio": 1.04,
    "max_smooth_ratio": 1.06,
    "seed_spread": 0.01,
    "invariance_spread": 0.01,
    "seconds_up_to_200": 30.0,
    "seconds_over_200": 300.0,
}
#: Instances of up to this many targets are held to the shorter time.
SMALL = 200


@dataclass(frozen=True)
class Case:
    """One benchmark case: an instance file, the factor on its radii and the best published length."""

    table: str
    name: str
    file: Path
    radius_factor: float
    bks: float | None
    source: str


def table_path(table: str) -> Path:
    """The CSV of a table: one shipped with the studies by name, or a path."""
    return TABLES.get(table, Path(table))


@functools.lru_cache(maxsize=32)
def read_table(table: str) -> dict[str, Case]:
    """The cases of a table by name.

    Raises
    ------
    ConfigError
        Naming the table when it cannot be read, lacks a column, repeats a name or has a bad number.
    """
    path = table_path(table)
    try:
        with path.open(newline="") as fh:
            rows = list(csv.DictReader(fh))
    except OSError as err:
        known = ", ".join(TABLES)
        raise ConfigError(f"--tables: {table!r} is neither {known} nor a readable CSV ({err}).") from None
    out: dict[str, Case] = {}
    for n, row in enumerate(rows, start=2):
        missing = [c for c in ("name", "file", "radius_factor") if not (row.get(c) or "").strip()]
        if missing:
            raise ConfigError(f"--tables: {path}, line {n}: no {missing[0]!r}.")
        name = row["name"].strip()
        if name in out:
            raise ConfigError(f"--tables: {path}, line {n}: case {name!r} twice.")
        try:
            factor = float(row["radius_factor"])
            bks = float(row["bks"]) if (row.get("bks") or "").strip() else None
        except ValueError as err:
            raise ConfigError(f"--tables: {path}, line {n}: {err}.") from None
        if not (math.isfinite(factor) and factor > 0) or (
            bks is not None and not (math.isfinite(bks) and bks > 0)
        ):
            raise ConfigError(f"--tables: {path}, line {n}: radius_factor and bks must be positive.")
        source = (row.get("bks_source") or "").strip()
        out[name] = Case(table, name, path.parent / row["file"].strip(), factor, bks, source)
    if not out:
        raise ConfigError(f"--tables: {path} lists no case.")
    return out


def case_of(table: str, name: str) -> Case:
    """Case ``name`` of ``table`` (:class:`ConfigError` when it has none of that name)."""
    cases = read_table(table)
    if name not in cases:
        raise ConfigError(f"--cases: {table} has no case {name!r} (it has {', '.join(cases)}).")
    return cases[name]


def instance(case: Case, scale: float = 1.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Depot ``(2,)``, centres ``(N, 2)`` and radii ``(N,)`` of a case, coordinates and radii times
    ``scale``."""
    depot, centres, radii = read_mennell(case.file, case.radius_factor)
    return depot * scale, centres * scale, radii * scale


def scenario(case: Case, horizon: int, scale: float = 1.0) -> Scenario:
    """The case as a scenario: the depot the one start, each target's own radius, the area the box of
    the depot and every disc."""
    depot, centres, radii = instance(case, scale)
    lo = np.minimum(depot, (centres - radii[:, None]).min(axis=0))
    hi = np.maximum(depot, (centres + radii[:, None]).max(axis=0))
    return Scenario(
        locales=centres,
        starts=depot[None],
        horizon=horizon,
        coverage_radius=radii,
        bounds=(float(lo[0]), float(hi[0]), float(lo[1]), float(hi[1])),
        name=case.name,
    )


def polyline_length(points: np.ndarray) -> float:
    """Length of the polyline through ``points (K, 2)``."""
    return float(np.hypot(*np.diff(np.asarray(points, dtype=float), axis=0).T).sum())


def trial(table: str, case: str, seed: int, horizon: int, scale: float) -> dict[str, Any]:
    """Plan one case (closed tour from the depot, per-target radii, default coverage settings, the
    planner's seed ``seed``) and measure both paths independently (module notes)."""
    c = case_of(table, case)
    sc = scenario(c, horizon, scale)
    depot, centres, radii = sc.start_positions[0], sc.locales, sc.radii
    settings = Settings(seed=seed, constraints=[Terminal.return_to_base()])
    searched = [0.0]

    def seen(progress: Any) -> None:
        searched[0] = float(progress.elapsed)

    cpu, wall = time.process_time(), time.perf_counter()
    res = plan(sc, "coverage", settings=settings, callback=seen)
    cpu, wall = time.process_time() - cpu, time.perf_counter() - wall
    tours = [np.asarray(p, dtype=float) for p in res.extras["tour"]]
    paths = [np.asarray(p, dtype=float) for p in res.positions]
    straight = sum(polyline_length(p) for p in tours) / scale
    smooth = sum(polyline_length(p) for p in paths) / scale
    straight_gaps = relative_gaps(centres, radii, tours)
    smooth_gaps = relative_gaps(centres, radii, paths)
    ends = [np.hypot(*(p[[0, -1]] - depot).T).max() / scale for p in tours]
    smooth_ends = [np.hypot(*(p[[0, -1]] - depot).T).max() / scale for p in paths]
    search = res.extras["search"]
    return {
        "targets": len(radii),
        "bks": c.bks,
        "straight": straight,
        "smooth": smooth,
        "straight_ratio": None if c.bks is None else straight / c.bks,
        "smooth_ratio": None if c.bks is None else smooth / c.bks,
        "smooth_over_straight": smooth / straight,
        "straight_gap": float(straight_gaps.max()),
        "smooth_gap": float(smooth_gaps.max()),
        "straight_covered": covered_fraction(straight_gaps),
        "smooth_covered": covered_fraction(smooth_gaps),
        "straight_end": float(max(ends)),
        "smooth_end": float(max(smooth_ends)),
        "iterations": int(search["iterations"]),
        "stages": {k: float(v) / scale for k, v in search["stages"].items()},
        "search_s": searched[0],
        "cpu": cpu,
        "wall": wall,
    }


#: What a trial records (module notes).
RESULTS = {
    "targets": "int",
    "bks": "float?",
    "straight": "float",
    "smooth": "float",
    "straight_ratio": "float?",
    "smooth_ratio": "float?",
    "smooth_over_straight": "float",
    "straight_gap": "float",
    "smooth_gap": "float",
    "straight_covered": "float",
    "smooth_covered": "float",
    "straight_end": "float",
    "smooth_end": "float",
    "iterations": "int",
    "stages": "dict",
    "search_s": "float",
    **TIME_COLUMNS,
}
#: The smooth path comes from the flight's constrained M-steps: their backends' tolerance.
SMOOTH = Check(
    "close", rtol=1e-5, atol=1e-9, reason="the flight's constrained M-steps agree to their tolerance"
)
#: A relative gap near zero (a disc met at its radius) is as close as the M-steps' tolerance allows.
GAP = Check("close", rtol=1e-5, atol=1e-6, reason="discs met at their radius, to the M-steps' tolerance")
CHECKS: Mapping[str, Check] = {
    **TIME_CHECKS,
    "search_s": Check("skip", reason="wall-clock time differs from run to run"),
    "smooth": SMOOTH,
    "smooth_ratio": SMOOTH,
    "smooth_over_straight": SMOOTH,
    "smooth_end": Check("close", rtol=0.0, atol=1e-6, reason="end position to the M-steps' tolerance"),
    "smooth_gap": GAP,
    "straight_gap": GAP,
}
TABLE = TrialTable.of("cetsp", trial, RESULTS, CHECKS)


def smallest_cases(tables: Sequence[str], k: int = 2) -> tuple[str, ...]:
    """The ``k`` cases of ``tables`` with the fewest targets (``--quick``)."""
    sizes = []
    for table in tables:
        for case in read_table(table).values():
            sizes.append((len(instance(case)[2]), case.name))
    return tuple(name for _, name in sorted(sizes)[:k])


@dataclass(frozen=True)
class Options(StudyOptions):
    """Options of ``pmht-opt study cetsp``."""

    tables: tuple[str, ...] = option(
        ("development",),
        Texts("--tables", "tables of cases: development, extra, or CSV files (default: development)"),
    )
    cases: tuple[str, ...] = option(
        (), Texts("--cases", "only these cases of the tables (default: every case)", empty=True)
    )
    seeds: tuple[int, ...] = option(SEEDS, Integers("--seeds", "planner seeds (default 0 1 2)"))
    horizon: int = option(
        HORIZON, Count("--horizon", "time steps T of the smooth path (default 1000)", minimum=2)
    )
    invariance_horizons: tuple[int, ...] = option(
        INVARIANCE_HORIZONS,
        Integers(
            "--invariance-horizons", "horizons of the invariance rows (default 500 1000 2000)", minimum=2
        ),
    )
    invariance_scales: tuple[float, ...] = option(
        INVARIANCE_SCALES,
        Positives("--invariance-scales", "scales of the invariance rows (default 0.01 1 100)"),
    )
    invariance: bool = option(True, Without("--no-invariance", "no invariance rows"))
    quick: bool = option(
        False,
        Flag(
            "--quick",
            "a run of seconds: the two smallest cases, seed 0, T = 200, invariance at T = 100 200 400 "
            "(options given still apply)",
        ),
    )

    def __post_init__(self) -> None:
        super().__post_init__()
        known: set[str] = set()
        for table in self.tables:
            known.update(read_table(table))
        unknown = [c for c in self.cases if c not in known]
        if unknown:
            raise ConfigError(f"--cases: no case {unknown[0]!r} in {', '.join(self.tables)}.")

    @classmethod
    def add_arguments(cls, p: Any) -> None:
        """The options, each defaulting to "not given" (``--quick`` chooses other defaults)."""
        for _, spec in cls._options():
            spec.add(p, None)

    @classmethod
    def from_args(cls, ns: Any) -> Options:
        """The options given, the others at their defaults (those of ``--quick`` when it is given)."""
        values: dict[str, Any] = {}
        for name, spec in cls._options():
            given = getattr(ns, spec.dest)
            if given is not None:
                values[name] = spec.read(given)
        if values.get("quick"):
            for name, value in QUICK.items():
                values.setdefault(name, value)
            if "cases" not in values:
                values["cases"] = smallest_cases(values.get("tables", ("development",)))
        return cls(**values)


def selected(options: Options) -> list[Case]:
    """The cases of the run, table by table in the tables' order."""
    out = []
    for table in options.tables:
        out += [c for c in read_table(table).values() if not options.cases or c.name in options.cases]
    return out


def params(options: Options) -> list[dict[str, Any]]:
    """Every seed of every case at the horizon, then (unless turned off) each case's invariance rows
    with the first seed; a trial named twice is one trial."""
    out: list[dict[str, Any]] = []
    cases = selected(options)

    def add(c: Case, seed: int, horizon: int, scale: float) -> None:
        p = {"table": c.table, "case": c.name, "seed": seed, "horizon": horizon, "scale": float(scale)}
        if p not in out:
            out.append(p)

    for c in cases:
        for seed in options.seeds:
            add(c, seed, options.horizon, 1.0)
    if options.invariance:
        for c in cases:
            for h in options.invariance_horizons:
                add(c, options.seeds[0], h, 1.0)
            for s in options.invariance_scales:
                add(c, options.seeds[0], options.horizon, s)
    return out


def _spread(values: Sequence[float]) -> float | None:
    """worst / best - 1 of the finite values (``None`` for fewer than one)."""
    vals = [v for v in values if v is not None and math.isfinite(v)]
    return max(vals) / min(vals) - 1 if vals else None


def _max(values: Sequence[float | None]) -> float | None:
    vals = [v for v in values if v is not None and math.isfinite(v)]
    return max(vals) if vals else None


def _mean(values: Sequence[float | None]) -> float | None:
    vals = [v for v in values if v is not None and math.isfinite(v)]
    return sum(vals) / len(vals) if vals else None


def _case_summary(rows: Sequence[Mapping[str, Any]], options: Options, name: str) -> dict[str, Any]:
    """One case: ratios per seed, seed spread, times, coverage, invariance spreads, errors."""
    main = [r for r in rows if r["horizon"] == options.horizon and r["scale"] == 1.0]
    main = sorted((r for r in main if r["seed"] in options.seeds), key=lambda r: r["seed"])
    ok = [r for r in main if not r["error_class"]]
    errors = [
        {k: r[k] for k in ("seed", "horizon", "scale", "error_class", "error")}
        for r in rows
        if r["error_class"]
    ]
    good = [r for r in rows if not r["error_class"]]
    entry: dict[str, Any] = {
        "case": name,
        "targets": good[0]["targets"] if good else None,
        "bks": good[0]["bks"] if good else None,
        "runs": len(ok),
        "errors": errors,
        "seeds": [r["seed"] for r in ok],
    }
    for kind in ("straight", "smooth"):
        ratios = [r[f"{kind}_ratio"] for r in ok]
        entry[f"{kind}_ratio"] = ratios
        entry[f"{kind}_ratio_mean"] = _mean(ratios)
        entry[f"{kind}_ratio_worst"] = _max(ratios)
        entry[f"{kind}_seed_spread"] = _spread([r[kind] for r in ok])
        entry[f"{kind}_gap_worst"] = _max([r[f"{kind}_gap"] for r in good])
    entry["smooth_over_straight_mean"] = _mean([r["smooth_over_straight"] for r in ok])
    entry["covered"] = bool(good) and all(r["straight_gap"] <= RTOL and r["smooth_gap"] <= RTOL for r in good)
    entry["closed"] = bool(good) and all(
        r["straight_end"] <= 1e-9 * max(1.0, r["straight"])
        and r["smooth_end"] <= 1e-6 * max(1.0, r["smooth"])
        for r in good
    )
    entry["max_wall"] = _max([r["wall"] for r in ok])
    entry["max_cpu"] = _max([r["cpu"] for r in ok])
    entry["max_search_s"] = _max([r["search_s"] for r in ok])
    entry["iterations"] = [r["iterations"] for r in ok]
    if ok and ok[0]["bks"]:
        stages = ok[0]["stages"].keys()
        entry["stage_ratio_mean"] = {k: _mean([r["stages"][k] / r["bks"] for r in ok]) for k in stages}
    if options.invariance:
        first = options.seeds[0]
        inv: dict[str, Any] = {}
        for axis, key, values, fixed in (
            ("horizon", "horizon", options.invariance_horizons, ("scale", 1.0)),
            ("scale", "scale", options.invariance_scales, ("horizon", options.horizon)),
        ):
            found = {}
            for v in values:
                match = [r for r in good if r["seed"] == first and r[key] == v and r[fixed[0]] == fixed[1]]
                if match:
                    found[f"{v:g}"] = {"straight": match[0]["straight"], "smooth": match[0]["smooth"]}
            inv[axis] = found
            for kind in ("straight", "smooth"):
                inv[f"{axis}_spread_{kind}"] = _spread([f[kind] for f in found.values()])
        entry["invariance"] = inv
    return entry


def _target(what: str, value: float | None, limit: float, note: str = "") -> dict[str, Any]:
    return {
        "target": what,
        "value": value,
        "limit": limit,
        "met": value is not None and value <= limit,
        **({"note": note} if note else {}),
    }


def table_summary(rows: Sequence[Mapping[str, Any]], options: Options, table: str) -> dict[str, Any]:
    """One table: every case, the aggregates over its cases and the targets."""
    names = [c.name for c in selected(options) if c.table == table]
    cases = [
        _case_summary([r for r in rows if r["table"] == table and r["case"] == n], options, n) for n in names
    ]
    t = TARGETS
    agg: dict[str, Any] = {"cases": len(cases), "errors": sum(len(c["errors"]) for c in cases)}
    for kind in ("straight", "smooth"):
        agg[f"mean_{kind}_ratio"] = _mean([c[f"{kind}_ratio_mean"] for c in cases])
        agg[f"max_{kind}_ratio"] = _max([c[f"{kind}_ratio_worst"] for c in cases])
        agg[f"max_{kind}_seed_spread"] = _max([c[f"{kind}_seed_spread"] for c in cases])
    agg["mean_smooth_over_straight"] = _mean([c["smooth_over_straight_mean"] for c in cases])
    small = [c for c in cases if c["targets"] is not None and c["targets"] <= SMALL]
    large = [c for c in cases if c["targets"] is not None and c["targets"] > SMALL]
    agg["max_wall"] = _max([c["max_wall"] for c in cases])
    agg["max_cpu"] = _max([c["max_cpu"] for c in cases])
    agg["max_wall_up_to_200"] = _max([c["max_wall"] for c in small])
    agg["max_cpu_up_to_200"] = _max([c["max_cpu"] for c in small])
    agg["max_wall_over_200"] = _max([c["max_wall"] for c in large])
    agg["max_cpu_over_200"] = _max([c["max_cpu"] for c in large])
    agg["all_covered"] = all(c["covered"] for c in cases)
    agg["all_closed"] = all(c["closed"] for c in cases)
    targets = [
        _target("mean straight / BKS", agg["mean_straight_ratio"], t["mean_straight_ratio"]),
        _target("every straight / BKS", agg["max_straight_ratio"], t["max_straight_ratio"]),
        _target("mean smooth / BKS", agg["mean_smooth_ratio"], t["mean_smooth_ratio"]),
        _target("every smooth / BKS", agg["max_smooth_ratio"], t["max_smooth_ratio"]),
        _target("seeds' worst / best - 1, straight", agg["max_straight_seed_spread"], t["seed_spread"]),
        _target("seeds' worst / best - 1, smooth", agg["max_smooth_seed_spread"], t["seed_spread"]),
    ]
    # Wall seconds are the target; CPU seconds show what the load of a shared machine added.
    for group, size, limit in (
        (small, "up_to_200", "seconds_up_to_200"),
        (large, "over_200", "seconds_over_200"),
    ):
        if group:
            for clock in ("wall", "cpu"):
                what = f"{clock} s per plan, {size.replace('_', ' ')} targets"
                targets.append(_target(what, agg[f"max_{clock}_{size}"], t[limit]))
    if options.invariance:
        for axis in ("horizon", "scale"):
            for kind in ("straight", "smooth"):
                key = f"{axis}_spread_{kind}"
                agg[f"max_{key}"] = _max([c["invariance"][key] for c in cases])
                targets.append(
                    _target(
                        f"invariance in the {axis}, {kind} (max / min - 1)",
                        agg[f"max_{key}"],
                        t["invariance_spread"],
                    )
                )
    targets.append(
        {
            "target": "every target covered on the segments, both paths",
            "value": agg["all_covered"],
            "met": agg["all_covered"],
        }
    )
    targets.append(
        {"target": "no plan failed", "value": agg["errors"], "limit": 0, "met": agg["errors"] == 0}
    )
    return {
        "table": table,
        "horizon": options.horizon,
        "seeds": list(options.seeds),
        "cases": cases,
        "aggregate": agg,
        "targets": targets,
    }


def summary(rows: Sequence[Mapping[str, Any]], options: Options) -> list[dict[str, Any]]:
    """Per table of the run: its cases, aggregates and targets."""
    return [table_summary(rows, options, table) for table in options.tables]


def _f(value: Any, digits: int = 4) -> str:
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return "-"
    return f"{value:.{digits}f}"


def _pct(value: Any) -> str:
    return "-" if value is None else f"{100 * value:.2f}%"


def markdown(table: Sequence[Mapping[str, Any]]) -> str:
    """The summary as markdown: per table, the cases, the aggregates and the targets."""
    parts = []
    for t in table:
        head = (
            f"## {t['table']}: T = {t['horizon']}, seeds {' '.join(map(str, t['seeds']))}\n\n"
            "| case | N | straight / BKS per seed | smooth / BKS per seed | seed spread straight / smooth "
            "| covered | max wall s (cpu) | T spread straight / smooth | scale spread straight / smooth "
            "| errors |\n"
            "|---|---|---|---|---|---|---|---|---|---|"
        )
        lines = [head]
        for c in t["cases"]:
            inv = c.get("invariance", {})
            lines.append(
                f"| {c['case']} | {c['targets'] if c['targets'] is not None else '-'} "
                f"| {' '.join(_f(v) for v in c['straight_ratio'])} "
                f"| {' '.join(_f(v) for v in c['smooth_ratio'])} "
                f"| {_pct(c['straight_seed_spread'])} / {_pct(c['smooth_seed_spread'])} "
                f"| {'yes' if c['covered'] else 'NO'} "
                f"| {_f(c['max_wall'], 1)} ({_f(c['max_cpu'], 1)}) "
                f"| {_pct(inv.get('horizon_spread_straight'))} / {_pct(inv.get('horizon_spread_smooth'))} "
                f"| {_pct(inv.get('scale_spread_straight'))} / {_pct(inv.get('scale_spread_smooth'))} "
                f"| {len(c['errors'])} |"
            )
        a = t["aggregate"]
        lines += [
            "",
            f"Over {a['cases']} cases: straight / BKS mean {_f(a['mean_straight_ratio'])}, max "
            f"{_f(a['max_straight_ratio'])}; smooth / BKS mean {_f(a['mean_smooth_ratio'])}, max "
            f"{_f(a['max_smooth_ratio'])}; smooth / straight mean {_f(a['mean_smooth_over_straight'])}. "
            f"Largest wall time {_f(a['max_wall'], 1)} s (CPU {_f(a['max_cpu'], 1)} s).",
            "",
            "| target | value | limit | met |",
            "|---|---|---|---|",
        ]
        for g in t["targets"]:
            value = g["value"]
            shown = _f(value) if isinstance(value, float) else str(value)
            lines.append(
                f"| {g['target']} | {shown} | {g.get('limit', '')} | {'yes' if g['met'] else 'NO'} |"
            )
        errors = [(c["case"], e) for c in t["cases"] for e in c["errors"]]
        if errors:
            lines += ["", "Failed plans:", ""]
            lines += [
                f"- {case} seed {e['seed']} T {e['horizon']} scale {e['scale']:g}: "
                f"{e['error_class']}: {e['error']}"
                for case, e in errors
            ]
        parts.append("\n".join(lines))
    return "\n\n".join(parts)


def main(run: RunOptions, options: Options) -> list[Path]:
    """Run the study into ``run.out``: ``cetsp.jsonl``, ``cetsp_summary.json`` and ``cetsp.md``."""
    out, rows = run.run_trials(TABLE, params(options))
    table = summary(rows, options)
    return run.publish(TABLE, out, table, markdown(table), rows=rows)


if __name__ == "__main__":
    from studies.cli import run_script

    run_script("cetsp", __file__)
