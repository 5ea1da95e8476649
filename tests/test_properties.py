"""Property-based tests of the validation boundary (pmht_opt.validation).

For any input to scenario construction and files, configs, constraints and the command line, the
outcome is one of two: the project's own exception naming the field that is wrong, or a plan that is
finite (and, with hard constraints, verified). Inputs mix valid values across the whole of the ranges
the numerics handle (docs/model.md section 14) with junk: strings that look like numbers, booleans,
``None``, integers beyond the float range, non-finite and out-of-range numbers, ragged arrays.

Sizes stay small (horizons of 20 to 40, the fast "auto" smoother) so the "ci" profile takes a few
seconds; ``HYPOTHESIS_PROFILE=long`` draws ten times as many examples (tests/conftest.py).
"""

from __future__ import annotations

import contextlib
import io
import json
import math
import tempfile
from pathlib import Path
from typing import Any

import numpy as np
from conftest import examples
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st

import pmht_opt as po
from pmht_opt import cli, validation
from pmht_opt.exceptions import ConfigError, InfeasibleError, PmhtOptError, ScenarioError, SolverError
from pmht_opt.toml_writer import dumps

# ------------------------------------------------------------------ strategies


def log_uniform(lo: float, hi: float) -> st.SearchStrategy[float]:
    """Floats spread evenly in magnitude over ``[lo, hi]``, the ends included."""
    inner = st.floats(math.log10(lo), math.log10(hi)).map(lambda e: min(hi, max(lo, 10.0**e)))
    return st.one_of(st.sampled_from([lo, hi]), inner)


#: Values that are never a number: strings that look like one, booleans, None, containers.
NOT_A_NUMBER = st.one_of(
    st.sampled_from(["1", "1e-8", "3", "", "nan", True, False, None]),
    st.lists(st.integers(0, 3), max_size=2),
    st.dictionaries(st.text(max_size=2), st.integers(), max_size=1),
)
#: Numbers that are never finite or that no float holds.
NOT_FINITE = st.sampled_from([math.nan, math.inf, -math.inf, 10**400, -(10**400)])


def junk_number(lo: float, hi: float) -> st.SearchStrategy[Any]:
    """Anything but a number in ``[lo, hi]``."""
    below = st.floats(max_value=lo, exclude_max=True, allow_nan=False, allow_infinity=False)
    above = st.floats(min_value=hi, exclude_min=True, allow_nan=False, allow_infinity=False)
    return st.one_of(NOT_A_NUMBER, NOT_FINITE, below, above)


def junk_integer(lo: int, hi: int) -> st.SearchStrategy[Any]:
    """Anything but an integer in ``[lo, hi]``: floats (even whole ones) are not integers."""
    floats = st.floats(allow_nan=True, allow_infinity=True)
    return st.one_of(NOT_A_NUMBER, st.integers(max_value=lo - 1), st.integers(min_value=hi + 1), floats)


@st.composite
def points(draw: st.DrawFn, width: int = 2, rows: tuple[int, int] = (1, 5)) -> np.ndarray:
    """A valid array of points: any size of area from 1e-3 to the coordinates' full range."""
    n = draw(st.integers(*rows))
    scale = draw(log_uniform(1e-3, validation.COORDINATE_MAX))
    centre = draw(st.floats(-1.0, 1.0)) * (validation.COORDINATE_MAX - scale)
    unit = draw(st.lists(st.floats(-1.0, 1.0), min_size=n * width, max_size=n * width))
    return np.clip(centre + scale * np.array(unit).reshape(n, width), -1e7, 1e7)


@st.composite
def junk_points(draw: st.DrawFn) -> Any:
    """Anything but a valid ``(K, 2)`` array of coordinates."""
    good = draw(points()).tolist()
    i = draw(st.integers(0, len(good) - 1))
    how = draw(st.sampled_from(["element", "ragged", "shape", "empty", "scalar", "far"]))
    if how == "element":
        good[i][draw(st.integers(0, 1))] = draw(st.one_of(NOT_A_NUMBER, NOT_FINITE))
    elif how == "ragged":
        good[i] = good[i][:1]
        good.append([1.0, 2.0])
    elif how == "shape":
        good = [[*row, 0.0] for row in good]
    elif how == "empty":
        good = []
    elif how == "scalar":
        return draw(st.one_of(NOT_A_NUMBER, st.floats()))
    else:
        good[i][0] = draw(st.sampled_from([-1.0, 1.0])) * draw(st.floats(1.0000001e7, 1e300))
    return good


VALID: dict[str, st.SearchStrategy[Any]] = {
    "horizon": st.integers(*validation.HORIZON_RANGE),
    "dt": log_uniform(*validation.DT_RANGE),
    "q": log_uniform(*validation.Q_RANGE),
    "r": log_uniform(*validation.R_RANGE),
    "coverage_radius": log_uniform(1e-12, validation.RADIUS_MAX),
    "name": st.text(st.characters(exclude_categories=("Cs",)), max_size=12),
    "bounds": st.one_of(st.none(), points(rows=(2, 2)).map(lambda p: (*np.sort(p[:, 0]), *np.sort(p[:, 1])))),
    "locales": points(),
    "starts": points(),
}
JUNK: dict[str, st.SearchStrategy[Any]] = {
    "horizon": junk_integer(*validation.HORIZON_RANGE),
    "dt": junk_number(*validation.DT_RANGE),
    "q": junk_number(*validation.Q_RANGE),
    "r": junk_number(*validation.R_RANGE),
    "coverage_radius": st.one_of(junk_number(0.0, validation.RADIUS_MAX), st.just(0.0)),
    "name": st.one_of(st.integers(), st.none(), st.just("a\ud800b"), st.binary(max_size=3)),
    "bounds": st.one_of(
        st.sampled_from(
            ["1234", 5, (0, 1, 0), (1, 0, 0, 1), (0, 1, 0, "1"), (0, 1, 0, 1e8), (0, 1, 0, True)]
        ),
    ),
    "locales": junk_points(),
    "starts": junk_points(),
}


def junk_keys(keys: Any, most: int = 2) -> st.SearchStrategy[frozenset[str]]:
    """Which fields get junk: none (as often as not), else one or a few."""
    some = st.frozensets(st.sampled_from(sorted(keys)), min_size=1, max_size=most)
    return st.one_of(st.just(frozenset()), some)


@st.composite
def scenario_fields(draw: st.DrawFn, junk: bool = True) -> tuple[dict[str, Any], set[str]]:
    """Scenario keyword arguments, some replaced by junk (none unless ``junk``); the fields that were."""
    bad = set(draw(junk_keys(VALID))) if junk else set()
    fields = {key: draw(JUNK[key] if key in bad else VALID[key]) for key in VALID}
    return fields, bad


def named_field(err: Exception) -> str:
    """The field an error message names first, without an index (``"bounds[2]: ..."`` -> ``"bounds"``)."""
    return str(err).split(":")[0].split(" ")[0].split("[")[0]


# ------------------------------------------------------------------ scenarios


@settings(max_examples=examples(60))
@given(scenario_fields())
def test_a_scenario_is_built_or_refused_naming_a_wrong_field(case: tuple[dict[str, Any], set[str]]) -> None:
    fields, bad = case
    try:
        sc = po.Scenario(**fields)
    except ScenarioError as err:
        assert bad, f"a valid scenario was refused: {err}"
        assert named_field(err) in bad, (str(err), bad)
        event(f"refused: {named_field(err)}")
        return
    assert not bad, f"accepted junk in {bad}"
    event("built")
    assert sc.horizon == fields["horizon"] and np.all(np.isfinite(sc.initial_states))
    assert sc.bounds is not None and all(abs(b) <= validation.COORDINATE_MAX for b in sc.bounds)


@settings(max_examples=examples(30), suppress_health_check=[HealthCheck.too_slow])
@given(scenario_fields(junk=False), st.sampled_from([".toml", ".json"]))
def test_files_round_trip_every_valid_scenario(case: tuple[dict[str, Any], set[str]], suffix: str) -> None:
    sc = po.Scenario(**case[0])
    with tempfile.TemporaryDirectory() as tmp:
        back = po.Scenario.load(sc.save(Path(tmp) / "missing" / f"s{suffix}"))
    assert back.to_dict() == sc.to_dict()


JSONABLE = st.recursive(
    st.one_of(st.none(), st.booleans(), st.integers(), st.floats(), st.text(max_size=4)),
    lambda inner: st.one_of(
        st.lists(inner, max_size=3), st.dictionaries(st.text(max_size=3), inner, max_size=3)
    ),
    max_leaves=8,
)


def _file_text(data: dict[str, Any], suffix: str) -> str | None:
    """``data`` as the text of a ``suffix`` file, or ``None`` (counted as an event) where the format
    cannot express it."""
    try:
        return json.dumps(data) if suffix == ".json" else dumps(data)
    except (TypeError, ValueError):
        event("not expressible in the format")
        return None


@settings(max_examples=examples(60))
@given(
    scenario_fields(),
    st.dictionaries(st.sampled_from([*VALID, "speed", ""]), JSONABLE, max_size=3),
    st.sampled_from([".toml", ".json"]),
)
def test_any_scenario_file_is_read_or_refused_naming_the_field(
    case: tuple[dict[str, Any], set[str]], noise: dict[str, Any], suffix: str
) -> None:
    fields, _ = case
    data = {k: (v.tolist() if isinstance(v, np.ndarray) else v) for k, v in {**fields, **noise}.items()}
    text = _file_text(data, suffix)
    if text is None:
        return  # not expressible in the file format (bytes, surrogates): nothing to read
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / f"s{suffix}"
        path.write_text(text, encoding="utf-8", errors="surrogatepass")
        try:
            sc = po.Scenario.load(path)
        except ScenarioError as err:
            assert str(err).startswith((f"{path.name}: ", "Scenario file", "Unknown")), str(err)
            event("refused")
            return
    event("read")
    assert np.all(np.isfinite(sc.initial_states)) and validation.HORIZON_RANGE[0] <= sc.horizon


@settings(max_examples=examples(30))
@given(st.binary(max_size=60), st.sampled_from([".toml", ".json"]))
def test_any_bytes_are_read_or_refused(content: bytes, suffix: str) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / f"s{suffix}"
        path.write_bytes(content)
        try:
            po.Scenario.load(path)
            event("read")
        except ScenarioError:
            event("refused")


# ------------------------------------------------------------------ configs and plans

CONFIG_VALID: dict[str, st.SearchStrategy[Any]] = {
    "max_iter": st.integers(1, 3),
    "tol": st.one_of(st.just(0.0), log_uniform(1e-12, 1.0)),
    "snapshots": st.lists(st.integers(0, 3), max_size=2).map(tuple),
    "estep_gate": st.one_of(st.none(), st.just("auto"), log_uniform(1.0, 1e3)),
    "update_time_prior": st.booleans(),
    "anneal": st.one_of(st.none(), st.tuples(log_uniform(1e-10, 1e12), st.integers(0, 3))),
}
CONFIG_JUNK: dict[str, st.SearchStrategy[Any]] = {
    "max_iter": junk_integer(1, validation.MAX_ITERATIONS),
    "tol": st.one_of(NOT_A_NUMBER.filter(lambda v: v is not None), NOT_FINITE, st.floats(max_value=-1e-300)),
    "snapshots": st.one_of(st.just(("a",)), st.just((-1,)), st.just((1.5,)), st.just(5)),
    "estep_gate": st.one_of(st.sampled_from(["fast", True, 0, -1.0, math.nan, 10**400])),
    "update_time_prior": st.one_of(st.sampled_from(["yes", 1, None])),
    "anneal": st.sampled_from([("1", 3), (1.0, "3"), (1e13, 3), (-1.0, 3), (1.0, 10**12), "fast", 5]),
}


@settings(max_examples=examples(60), suppress_health_check=[HealthCheck.too_slow])
@given(scenario_fields(junk=False), st.data())
def test_a_plan_is_finite_or_refused_naming_the_field(
    case: tuple[dict[str, Any], set[str]], data: Any
) -> None:
    fields = case[0]
    fields["horizon"] = data.draw(st.integers(20, 40))
    sc = po.Scenario(**fields)
    bad = data.draw(junk_keys(CONFIG_VALID))
    kwargs = {key: data.draw(CONFIG_JUNK[key] if key in bad else CONFIG_VALID[key]) for key in CONFIG_VALID}
    kwargs["solver"] = data.draw(st.sampled_from(["auto", "banded"]))
    try:
        cfg = po.PMHTConfig(**kwargs)
    except ConfigError as err:
        assert bad and named_field(err).split(".")[0] in bad, (str(err), bad)
        event(f"refused: {named_field(err)}")
        return
    assert not bad, f"accepted junk in {bad}"
    try:
        res = po.plan_pmht(sc, cfg)
    except ConfigError as err:  # a schedule that does not start above this scenario's r
        assert named_field(err) == "anneal.start" and cfg.anneal.start <= sc.r, str(err)
        event("refused: anneal.start not above r")
        return
    event("planned")
    assert np.all(np.isfinite(res.states)) and res.n_iterations <= cfg.max_iter
    assert np.allclose(res.states[:, 0], sc.initial_states)
    m = res.metrics()
    assert math.isfinite(m["total_distance"]) and 0.0 <= m["coverage"] <= 1.0


def constraint(draw: st.DrawFn, sc: po.Scenario) -> tuple[Any, bool]:
    """A constraint of a random kind with random (sometimes junk) parameters; whether any is junk."""
    extent = max(sc.bounds[1] - sc.bounds[0], sc.bounds[3] - sc.bounds[2], 1e-3)  # type: ignore[index]
    size = log_uniform(min(1e-3 * extent, 1.0), min(1e3 * extent, 1e7))
    junk = draw(st.integers(0, 2)) == 2
    kind = draw(st.sampled_from(["speed", "accel", "area", "circle", "terminal", "visit"]))
    negative = st.just(-1.0) if kind != "terminal" else st.nothing()  # a final velocity may be negative
    bad = st.one_of(NOT_A_NUMBER, NOT_FINITE, negative, st.just(1e300))
    if kind == "visit":
        bad = bad.filter(lambda v: v is not None)  # VisitAll(None): the scenario's coverage radius
    if kind in ("speed", "accel"):
        bad = bad.filter(lambda v: not isinstance(v, list))  # a list: one limit per platform
    value = draw(bad if junk else size)
    if kind == "speed":
        return (lambda: po.SpeedLimit(value)), junk
    if kind == "accel":
        return (lambda: po.AccelLimit(value)), junk
    if kind == "visit":
        return (lambda: po.VisitAll(value, warmup=0)), junk
    if kind == "circle":
        far = (sc.bounds[1] + 2 * extent + 1.0, sc.bounds[3])  # type: ignore[index]
        return (lambda: po.CircleObstacle(far, value)), junk
    if kind == "area":
        b = sc.bounds
        assert b is not None
        xmax = value if junk else b[1] + 1.0
        return (lambda: po.AreaBounds(b[0] - 1.0, xmax, b[2] - 1.0, b[3] + 1.0)), junk
    return (lambda: po.Terminal(velocity=[value, 0.0] if junk else [0.0, 0.0])), junk


@settings(max_examples=examples(25), suppress_health_check=[HealthCheck.too_slow])
@given(st.data())
def test_constraints_are_refused_naming_the_field_or_plans_meet_them(data: Any) -> None:
    scale = data.draw(log_uniform(1.0, 1e5))
    unit = st.lists(st.tuples(st.floats(0, 1), st.floats(0, 1)), min_size=1, max_size=4)
    sc = po.Scenario(
        locales=scale * np.array(data.draw(unit)),
        starts=scale * np.array(data.draw(unit))[:2],
        horizon=data.draw(st.integers(20, 30)),
        r=(0.01 * scale) ** 2,
        q=1e-8 * scale**2,
        bounds=(0.0, scale, 0.0, scale),
    )
    make, junk = constraint(data.draw, sc)
    try:
        con = make()
    except ConfigError as err:
        assert junk, f"a valid constraint was refused: {err}"
        assert named_field(err).split(".")[0] in type(err).__name__ + str(err), str(err)
        event("refused")
        return
    assert not junk, "accepted a junk constraint parameter"
    cfg = po.PMHTConfig(max_iter=2, anneal=None, constraints=[con])
    try:
        res = po.plan_pmht(sc, cfg)
    except InfeasibleError:
        event("infeasible")
        return  # the project's own verdict, naming the constraint
    except ScenarioError as err:  # a start inside the obstacle: refused before planning
        assert "starts at" in str(err) and type(con).__name__ in str(err), str(err)
        event("start inside the obstacle")
        return
    except SolverError as err:
        assert "clarabel" in str(err), str(err)  # a solve the backend did not stand behind, said so
        event("solver error")
        return
    event("planned")
    assert np.all(np.isfinite(res.states))
    for rep in res.constraint_reports():
        assert rep.max_violation <= 1e-6 * max(1.0, con.scale(sc)) or rep.soft


# ------------------------------------------------------------------ the command line


def run_cli(argv: list[str]) -> tuple[int, str, str]:
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = cli.main(argv)
    return code, out.getvalue(), err.getvalue()


@settings(max_examples=examples(25), suppress_health_check=[HealthCheck.too_slow])
@given(
    scenario_fields(),
    st.sampled_from([".toml", ".json"]),
    st.sampled_from([1, 2, 3, 1, 2, 3, 0, -2, "x", "1.5", "", "1e9", "99999999999999999999"]),
)
def test_the_cli_plans_or_exits_2_with_one_line(
    case: tuple[dict[str, Any], set[str]], suffix: str, iterations: Any
) -> None:
    fields, bad = case
    fields["horizon"] = fields["horizon"] if "horizon" in bad else min(fields["horizon"], 30)
    # A field left out of the file is how a file says "not given" (bounds=None in the library).
    data = {k: (v.tolist() if isinstance(v, np.ndarray) else v) for k, v in fields.items() if v is not None}
    text = _file_text(data, suffix)
    if text is None:
        return
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / f"m{suffix}"
        path.write_text(text, encoding="utf-8", errors="surrogatepass")
        out = Path(tmp) / "out" / "plan.json"
        argv = [
            "plan",
            str(path),
            "--quiet",
            "--planner",
            "pmht",
            "--no-anneal",
            "--iterations",
            str(iterations),
            "--json",
            str(out),
        ]
        code, stdout, stderr = run_cli(argv)
        assert "Traceback" not in stderr
        if code == 0:
            payload = json.loads(out.read_text())
            assert np.all(np.isfinite(payload["positions"])) and "total distance" in stdout
            event("planned")
            return
        assert code == cli.EXIT_ERROR, (code, stderr)
        assert bad or iterations not in (1, 2, 3), f"a valid mission was refused: {stderr}"
        assert not out.exists()
        if stderr.startswith("usage:"):  # argparse's own message for an --iterations it cannot parse
            assert "argument --iterations" in stderr
            event("usage error")
            return
        assert stderr.startswith("pmht-opt: error: ") and stderr.count("\n") == 1, stderr
        message = stderr.removeprefix("pmht-opt: error: ").removeprefix(f"{path.name}: ")
        event(f"exit 2: {message.split(':')[0]}")


def test_the_cli_refuses_what_the_library_refuses() -> None:
    """A junk field read from a file is refused by the command line with the library's own message."""
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "m.json"
        path.write_text(json.dumps({"locales": [[1, 1]], "starts": [[0, 0]], "dt": 1e9}))
        code, _, stderr = run_cli(["plan", str(path), "--quiet"])
    assert code == cli.EXIT_ERROR
    with_library = ""
    try:
        po.Scenario(locales=[[1, 1]], starts=[[0, 0]], dt=1e9)
    except PmhtOptError as err:
        with_library = str(err)
    assert with_library and with_library in stderr
