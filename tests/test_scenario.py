"""Scenario validation, the paper's scenarios and scenario files."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import pmht_opt as po


def make(**changes: object) -> po.Scenario:
    fields: dict[str, object] = {"locales": [[1.0, 2.0], [3.0, 4.0]], "starts": [[0.0, 0.0]], "horizon": 10}
    fields.update(changes)
    return po.Scenario(**fields)  # type: ignore[arg-type]


@pytest.mark.parametrize(
    ("changes", "field"),
    [
        ({"locales": [[1.0, 2.0, 3.0]]}, "locales"),
        ({"locales": np.zeros((0, 2))}, "locales"),
        ({"locales": [[1.0, np.nan]]}, "locales"),
        ({"locales": [[1.0, "x"]]}, "locales"),
        ({"starts": [[0.0, 0.0, 0.0]]}, "starts"),
        ({"starts": [[np.inf, 0.0]]}, "starts"),
        ({"starts": np.zeros((0, 2))}, "starts"),
        ({"horizon": 1}, "horizon"),
        ({"horizon": -5}, "horizon"),
        ({"horizon": 2.5}, "horizon"),
        ({"dt": 0.0}, "dt"),
        ({"q": -1e-8}, "q"),
        ({"r": 0.0}, "r"),
        ({"r": float("nan")}, "r"),
        ({"bounds": (0, 1, 0)}, "bounds"),
        ({"bounds": (2, 1, 0, 1)}, "bounds"),
    ],
)
def test_bad_input_names_the_field(changes: dict, field: str) -> None:
    with pytest.raises(po.ScenarioError, match=field):
        make(**changes)


def test_scenario_error_is_a_value_error() -> None:
    with pytest.raises(ValueError):
        make(horizon=0)


def test_full_state_starts_are_kept() -> None:
    s = make(starts=[[1.0, 0.1, 0.0, 2.0, -0.1, 0.0]])
    np.testing.assert_array_equal(s.initial_states[0], [1.0, 0.1, 0.0, 2.0, -0.1, 0.0])
    np.testing.assert_array_equal(s.start_positions, [[1.0, 2.0]])


def test_position_starts_have_zero_speed() -> None:
    s = make(starts=[[1.0, 2.0]])
    np.testing.assert_array_equal(s.initial_states[0], [1.0, 0.0, 0.0, 2.0, 0.0, 0.0])


def test_paper_scenario_a_is_the_grid_with_four_random_platforms() -> None:
    s = po.paper_scenario("A", seed=3)
    assert s.n_locales == 100 and s.n_platforms == 4
    assert set(np.unique(s.locales)) == set(np.arange(10) + 0.5)
    assert np.all((s.start_positions >= 0) & (s.start_positions <= 10))
    assert (s.horizon, s.q, s.r, s.dt) == (500, 1e-8, 1e-2, 1.0)


def test_paper_scenario_b_has_fixed_starts_outside_the_map() -> None:
    s = po.paper_scenario("b", seed=3)
    np.testing.assert_array_equal(s.start_positions, [[-1, 2.5], [-1, 5], [-1, 7.5]])
    assert s.n_locales == 100
    assert np.all((s.locales >= 0) & (s.locales <= 10))


def test_paper_scenario_c_and_seeding() -> None:
    a = po.paper_scenario("C", seed=7)
    b = po.paper_scenario("C", seed=7)
    c = po.paper_scenario("C", seed=8)
    np.testing.assert_array_equal(a.locales, b.locales)
    np.testing.assert_array_equal(a.starts, b.starts)
    assert not np.array_equal(a.locales, c.locales)
    assert a.n_platforms == 4


def test_unknown_paper_scenario() -> None:
    with pytest.raises(po.ScenarioError, match="'A', 'B' and 'C'"):
        po.paper_scenario("D")


@pytest.mark.parametrize("suffix", [".toml", ".json"])
def test_file_round_trip(tmp_path: Path, suffix: str) -> None:
    s = po.paper_scenario("C", seed=2, horizon=123)
    path = s.save(tmp_path / f"scen{suffix}")
    back = po.Scenario.load(path)
    np.testing.assert_array_equal(back.locales, s.locales)
    np.testing.assert_array_equal(back.starts, s.starts)
    assert (back.horizon, back.dt, back.q, back.r, back.bounds, back.name) == (
        s.horizon,
        s.dt,
        s.q,
        s.r,
        s.bounds,
        s.name,
    )


@pytest.mark.parametrize(
    ("name", "text", "message"),
    [
        ("bad.json", "{not json", "not valid json"),
        ("bad.toml", "locales = [[1, 2]\n", "not valid toml"),
        ("missing.json", '{"locales": [[1, 2]]}', "no 'starts' field"),
        ("extra.json", '{"locales": [[1, 2]], "starts": [[0, 0]], "speed": 3}', "Unknown scenario field"),
        ("shape.json", '{"locales": [1, 2], "starts": [[0, 0]]}', "locales must have shape"),
        ("horizon.toml", "locales = [[1.0, 2.0]]\nstarts = [[0.0, 0.0]]\nhorizon = -3\n", "horizon"),
        ("list.json", "[1, 2, 3]", "table/object"),
        ("scen.yaml", "locales: []", ".toml or .json"),
        # Values of the wrong type or beyond what the numerics read: the message names the field.
        ("big.json", '{"locales": [[1, 1%s]], "starts": [[0, 0]]}' % ("0" * 400), "integer beyond the float"),
        ("big.toml", "locales = [[1, 1]]\nstarts = [[0, 0]]\nhorizon = 1%s\n" % ("0" * 400), "horizon"),
        ("long.json", '{"locales": [[1, 1%s]], "starts": [[0, 0]]}' % ("0" * 5000), "not valid json"),
        ("deep.json", "[" * 100_000 + "]" * 100_000, "nested too deeply"),
        ("deep.toml", "x = " + "[" * 100_000 + "]" * 100_000, "nested too deeply"),
        ("horizon.json", '{"locales": [[1, 1]], "starts": [[0, 0]], "horizon": "300"}', "horizon: expected"),
        ("q.toml", 'locales = [[1, 1]]\nstarts = [[0, 0]]\nq = "1e-8"\n', "q: expected"),
        ("bool.json", '{"locales": [[1, 1]], "starts": [[0, 0]], "dt": true}', "dt: expected"),
        ("strs.json", '{"locales": [["1", "2"]], "starts": [[0, 0]]}', "locales: expected numbers"),
        ("bounds.json", '{"locales": [[1, 1]], "starts": [[0, 0]], "bounds": "1234"}', "bounds: expected"),
    ],
)
def test_malformed_files_raise_scenario_error(tmp_path: Path, name: str, text: str, message: str) -> None:
    path = tmp_path / name
    path.write_text(text)
    with pytest.raises(po.ScenarioError, match=message):
        po.Scenario.load(path)


def test_missing_file() -> None:
    with pytest.raises(po.ScenarioError, match="Cannot read"):
        po.Scenario.load("/nonexistent/scenario.toml")
