"""Coverage radii of their own: one per locale, everywhere a coverage radius is used."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import pmht_opt as po
from pmht_opt.io import export_geojson, load_mission, read_radii

LOCALES = [[1.0, 1.0], [3.0, 1.0], [5.0, 1.0]]
RADII = [0.2, 0.5, 1.0]


def scenario(radius: object = RADII) -> po.Scenario:
    return po.Scenario(locales=LOCALES, starts=[[0.0, 0.0]], horizon=40, coverage_radius=radius)


def test_a_scenario_holds_one_radius_per_locale() -> None:
    sc = scenario()
    np.testing.assert_array_equal(sc.radii, RADII)
    assert sc.radius_text == "0.2-1"
    again = po.Scenario.from_dict(sc.to_dict())
    np.testing.assert_array_equal(again.coverage_radius, RADII)
    assert scenario([0.4, 0.4, 0.4]).coverage_radius == 0.4  # equal radii are the one number
    assert scenario(0.3).radii.tolist() == [0.3, 0.3, 0.3]


@pytest.mark.parametrize(
    ("radius", "match"),
    [
        ([0.2, 0.5], r"coverage_radius: expected one number or one per locale \(3,\)"),
        ([0.2, -0.5, 1.0], r"coverage_radius\[1\]: expected a number in \(0, 1e\+07\], got -0.5"),
        ([0.2, float("nan"), 1.0], r"coverage_radius\[1\]"),
        ("wide", "coverage_radius"),
    ],
)
def test_bad_radii_name_the_locale(radius: object, match: str) -> None:
    with pytest.raises(po.ScenarioError, match=match):
        scenario(radius)


def test_coverage_is_measured_against_each_locales_own_radius(tmp_path: Path) -> None:
    """A straight path along y = 1.6: 0.6 from every locale. Covered: only the locale of radius 1."""
    path = np.column_stack([np.linspace(0.0, 6.0, 41), np.full(41, 1.6)])
    sc = scenario()
    states = np.zeros((1, 41, 6))
    states[0, :, 0], states[0, :, 3] = path[:, 0], path[:, 1]
    res = po.PlanResult(sc, states, np.zeros(3, int), np.ones(3, int), np.ones((3, 1)), _history())
    assert res.missed_locales().tolist() == [0, 1]
    assert res.coverage() == pytest.approx(1 / 3) and res.coverage(0.7) == 1.0
    assert res.metrics()["coverage_radius"] == RADII
    out = export_geojson(res, tmp_path / "p.geojson")
    assert read_radii(out) == RADII


def _history() -> po.IterationHistory:
    return po.IterationHistory(np.zeros(1), np.zeros(1), np.zeros(0), np.zeros(0, int))


def test_guaranteed_visits_meet_each_locales_own_radius() -> None:
    res = po.plan_pmht(scenario(), po.PMHTConfig(max_iter=12, anneal=None, constraints=[po.VisitAll()]))
    assert res.coverage() == 1.0
    rep = res.constraint_reports()[0]
    assert rep.name == "VisitAll()" and rep.max_violation <= 1e-6


def test_a_sites_csv_gives_each_site_its_radius(tmp_path: Path) -> None:
    (tmp_path / "sites.csv").write_text("site,x,y,radius\na,1,1,0.2\nb,3,1,0.5\nc,5,1,1.0\n")
    (tmp_path / "m.toml").write_text('locales = "sites.csv"\nstarts = [[0.0, 0.0]]\nhorizon = 40\n')
    mission = load_mission(tmp_path / "m.toml")
    np.testing.assert_array_equal(mission.scenario.coverage_radius, RADII)
    (tmp_path / "m.toml").write_text(
        'locales = "sites.csv"\nstarts = [[0.0, 0.0]]\nhorizon = 40\ncoverage_radius = 0.3\n'
    )
    with pytest.raises(po.ScenarioError, match="gives each locale its own radius"):
        load_mission(tmp_path / "m.toml")
    (tmp_path / "sites.csv").write_text("site,x,y,radius\na,1,1,0.2\nb,3,1,none\nc,5,1,1.0\n")
    with pytest.raises(po.ScenarioError, match=r"sites.csv, 3: radius: expected a positive number"):
        load_mission(tmp_path / "m.toml")
