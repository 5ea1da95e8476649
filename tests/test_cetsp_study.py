"""The CETSP benchmark study: its data shipped with the package, its own coverage check, options, a tiny
run end to end with verify, and the summary's aggregates and targets."""

from __future__ import annotations

import csv
import fnmatch
import json
import tomllib
from pathlib import Path

import numpy as np
import pytest

from pmht_opt.cli import main
from pmht_opt.exceptions import ConfigError
from pmht_opt.tours import read_mennell
from studies import cetsp
from studies.cli import build_parser
from studies.segment_coverage import covered_fraction, relative_gaps, segment_distances
from studies.store import read_rows

ROOT = Path(__file__).resolve().parent.parent


def test_every_benchmark_file_is_package_data() -> None:
    data = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]["package-data"]
    assert "registry.toml" in data["studies"]  # the studies' list, which pmht-opt --help reads
    globs = [g for g in data["studies"] if g.startswith("benchmarks/")]
    base = ROOT / "studies"
    files = [p.relative_to(base).as_posix() for p in (base / "benchmarks").rglob("*") if p.is_file()]
    assert files and all(any(fnmatch.fnmatch(f, g) for g in globs) for f in files)
    assert all(any(fnmatch.fnmatch(f, g) for f in files) for g in globs)  # no glob matches nothing


@pytest.mark.parametrize("table", sorted(cetsp.TABLES))
def test_every_case_of_the_shipped_tables_reads_as_its_row_says(table: str) -> None:
    cases = cetsp.read_table(table)
    assert len(cases) == {"development": 16}.get(table, len(cases))
    with cetsp.TABLES[table].open() as fh:
        rows = {r["name"]: r for r in csv.DictReader(fh)}
    for name, case in cases.items():
        depot, _, radii = read_mennell(case.file, case.radius_factor)
        row = rows[name]
        assert len(radii) == int(row["targets"]), name
        assert case.bks is not None and case.bks > 0 and case.source
        if row.get("radius") not in (None, "", "varies"):
            assert np.allclose(radii, float(row["radius"]), rtol=1e-3), name
        if row.get("depot_x"):
            assert np.allclose(depot, [float(row["depot_x"]), float(row["depot_y"])]), name


def test_segment_coverage_measures_between_the_points() -> None:
    # A target midway between two samples is on the segment, far from both points.
    line = np.array([[0.0, 0.0], [10.0, 0.0], [10.0, 10.0]])
    centres = np.array([[5.0, 0.5], [10.5, 5.0], [12.0, 12.0]])
    d = segment_distances(centres, line)
    assert np.allclose(d, [0.5, 0.5, np.hypot(2.0, 2.0)])
    gaps = relative_gaps(centres, np.array([0.5, 0.4, 3.0]), [line])
    assert np.allclose(gaps, [0.0, 0.25, np.hypot(2.0, 2.0) / 3.0 - 1.0])
    assert covered_fraction(gaps) == pytest.approx(2 / 3)
    # The nearest of several polylines counts; one point is a polyline too.
    assert relative_gaps(centres[:1], 1.0, [line[2:], np.array([[5.0, 0.0]])])[0] == pytest.approx(-0.5)
    # Many targets against many segments (blocks) agree with a direct computation.
    rng = np.random.default_rng(1)
    pts, cs = rng.uniform(0, 1, (40, 2)), rng.uniform(0, 1, (600, 2))
    a, b = pts[:-1], pts[1:]
    u = np.clip(np.einsum("nsk,sk->ns", cs[:, None] - a, b - a) / np.sum((b - a) ** 2, axis=1), 0, 1)
    brute = np.linalg.norm(a + u[..., None] * (b - a) - cs[:, None], axis=2).min(axis=1)
    assert np.allclose(segment_distances(cs, pts), brute)


def _tiny_table(tmp_path: Path, bks: str = "") -> Path:
    (tmp_path / "tiny.cetsp").write_text(
        "//Depot: 0, 0, 0\n3 0 0 0.5 1\n3 3 0 0.5 1\n0 3 0 0.5 1\n6 1 0 1 1\n"
    )
    table = tmp_path / "tiny.csv"
    table.write_text(f"name,file,radius_factor,bks\ntiny,tiny.cetsp,1.0,{bks}\n")
    return table


def test_a_table_of_ones_own_and_a_trial_without_bks(tmp_path: Path) -> None:
    table = str(_tiny_table(tmp_path))
    row = cetsp.trial(table, "tiny", 0, 60, 1.0)
    assert row["targets"] == 4 and row["bks"] is None and row["straight_ratio"] is None
    assert row["straight_gap"] <= 1e-6 and row["smooth_gap"] <= 1e-6 and row["smooth_covered"] == 1.0
    assert row["smooth"] >= row["straight"] > 0 and row["straight_end"] == 0.0 and row["smooth_end"] < 1e-6
    assert set(row["stages"]) == {"centres", "cone", "descent", "search"}
    # The same case scaled by 100: the same lengths once scaled back.
    big = cetsp.trial(table, "tiny", 0, 60, 100.0)
    assert big["straight"] == pytest.approx(row["straight"], rel=1e-9)


def test_bad_options_name_the_option(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="--cases"):
        cetsp.Options(cases=("bubbles99",))
    with pytest.raises(ConfigError, match="--tables"):
        cetsp.Options(tables=(str(tmp_path / "none.csv"),))
    bad = tmp_path / "bad.csv"
    bad.write_text("name,file\nx,x.cetsp\n")
    with pytest.raises(ConfigError, match="radius_factor"):
        cetsp.Options(tables=(str(bad),))
    with pytest.raises(ConfigError, match="--seeds"):
        cetsp.Options(seeds=(-1,))
    with pytest.raises(ConfigError, match="--invariance-scales"):
        cetsp.Options(invariance_scales=(0.0,))


def test_quick_chooses_defaults_the_options_given_still_apply() -> None:
    parser = build_parser()
    quick = cetsp.Options.from_args(parser.parse_args(["cetsp", "--quick"]))
    assert quick.cases == ("concentricCircles1", "rotatingDiamonds1") and quick.seeds == (0,)
    assert quick.horizon == 200 and quick.invariance_horizons == (100, 200, 400)
    given = cetsp.Options.from_args(
        parser.parse_args(["cetsp", "--quick", "--seeds", "1", "--no-invariance"])
    )
    assert given.seeds == (1,) and not given.invariance and given.horizon == 200
    full = cetsp.Options.from_args(parser.parse_args(["cetsp"]))
    assert full == cetsp.Options() and full.seeds == (0, 1, 2) and full.horizon == 1000


def test_trials_of_a_run() -> None:
    opts = cetsp.Options(cases=("bubbles1", "kroD100_or2"))
    trials = cetsp.params(opts)
    # Per case: 3 seeds at T = 1000, then T = 500 and 2000 and scales 0.01 and 100 with seed 0.
    assert len(trials) == 2 * (3 + 4)
    assert [t["seed"] for t in trials[:3]] == [0, 1, 2] and trials[0]["table"] == "development"
    inv = [t for t in trials if t["case"] == "bubbles1" and (t["horizon"] != 1000 or t["scale"] != 1.0)]
    assert sorted((t["horizon"], t["scale"]) for t in inv) == [
        (500, 1.0),
        (1000, 0.01),
        (1000, 100.0),
        (2000, 1.0),
    ]
    assert len(cetsp.params(cetsp.Options(cases=("bubbles1",), invariance=False))) == 3


def test_cetsp_study_end_to_end(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    args = ["study", "cetsp", "--cases", "concentricCircles1", "--seeds", "0", "--horizon", "120"]
    args += ["--invariance-horizons", "120", "240", "--invariance-scales", "1", "100", "--out", str(tmp_path)]
    assert main([*args, "--quiet"]) == 0
    assert f"wrote: {tmp_path / 'cetsp.md'}" in capsys.readouterr().out
    rows = read_rows(tmp_path / "cetsp.jsonl", cetsp.TABLE.schema, "cetsp")
    assert sorted((r["horizon"], r["scale"]) for r in rows) == [(120, 1.0), (120, 100.0), (240, 1.0)]
    assert all(r["error_class"] == "" for r in rows)
    assert all(r["straight_ratio"] < 1.001 and r["smooth_covered"] == 1.0 for r in rows)
    (table,) = json.loads((tmp_path / "cetsp_summary.json").read_text())["summary"]
    (case,) = table["cases"]
    assert case["covered"] and case["closed"] and case["invariance"]["scale_spread_straight"] < 1e-9
    assert set(case["invariance"]["horizon"]) == {"120", "240"}
    met = {t["target"]: t["met"] for t in table["targets"]}
    assert met["every straight / BKS"] and met["no plan failed"]
    assert "| concentricCircles1 | 16 |" in (tmp_path / "cetsp.md").read_text()
    assert main([*args, "--verify", "1"]) == 0
    assert "agrees" in capsys.readouterr().out


def _row(case: str, seed: int, straight: float, smooth: float, **kw: object) -> dict[str, object]:
    row: dict[str, object] = {
        "table": "development",
        "case": case,
        "seed": seed,
        "horizon": 1000,
        "scale": 1.0,
        "error_class": "",
        "error": "",
        "targets": 50,
        "bks": 100.0,
        "straight": straight,
        "smooth": smooth,
        "straight_ratio": straight / 100.0,
        "smooth_ratio": smooth / 100.0,
        "smooth_over_straight": smooth / straight,
        "straight_gap": -0.1,
        "smooth_gap": 0.0,
        "straight_end": 0.0,
        "smooth_end": 0.0,
        "iterations": 10,
        "stages": {"search": straight},
        "search_s": 1.0,
        "wall": 2.0,
        "cpu": 1.0,
    }
    row.update(kw)
    return row


def test_summary_aggregates_and_targets() -> None:
    opts = cetsp.Options(cases=("bubbles1", "bubbles2"), seeds=(0, 1), invariance=False)
    rows = [
        _row("bubbles1", 0, 100.0, 103.0),
        _row("bubbles1", 1, 102.0, 104.0),
        _row("bubbles2", 0, 101.0, 108.0, wall=40.0),
        {**_row("bubbles2", 1, 1.0, 1.0), "error_class": "SolverError", "error": "failed"},
    ]
    (table,) = cetsp.summary(rows, opts)
    agg = table["aggregate"]
    assert agg["mean_straight_ratio"] == pytest.approx((1.01 + 1.01) / 2)
    assert agg["max_smooth_ratio"] == pytest.approx(1.08)
    assert agg["max_straight_seed_spread"] == pytest.approx(0.02) and agg["errors"] == 1
    met = {t["target"]: t["met"] for t in table["targets"]}
    assert met["mean straight / BKS"] and not met["every smooth / BKS"]
    assert not met["wall s per plan, up to 200 targets"] and not met["no plan failed"]
    assert not met["seeds' worst / best - 1, straight"]
    text = cetsp.markdown([table])
    assert "bubbles2 seed 1 T 1000 scale 1: SolverError: failed" in text
