"""``pmht-opt study scaling --quick`` writes its tables, figure and agreement figures."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest

from pmht_opt.cli import main as cli_main
from studies.scaling_study.design import scaling_scenario
from studies.scaling_study.measure import agreement, time_plan
from studies.scaling_study.summary import fit_slope


def test_scaling_study_quick(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    args = ["study", "scaling", "--quick", "--backends", "kalman", "--out", str(tmp_path), "--quiet"]
    code = cli_main(args)
    assert code == 0
    for name in ("scaling.jsonl", "scaling.json", "scaling.md", "scaling.png"):
        assert (tmp_path / name).stat().st_size > 0
    summary = json.loads((tmp_path / "scaling.json").read_text())
    assert summary["fastest"] == "kalman"
    assert set(summary["sweeps"]) == {"N", "T", "M"}
    assert summary["headline"]["auto"]["runs"] == 1 and summary["headline"]["off"]["runs"] == 1
    assert all(a["assignment_equal"] for a in summary["agreement"])
    assert "## Gated against dense" in (tmp_path / "scaling.md").read_text()
    scale = summary["scale"]
    assert scale["size"] == [120, 100, 4] and scale["runs"] == 1 and not scale["errors"]
    assert 0 < scale["estep_gated_calls"] <= scale["estep_calls"]  # plain EM gates from the start
    assert scale["target"]["met"] is None and "not the target's size" in scale["target"]["verdict"]
    assert "## Scale point N = 120" in (tmp_path / "scaling.md").read_text()
    assert cli_main(["study", "scaling", "--quick", "--reps", "0", "--out", str(tmp_path), "--quiet"]) == 2
    # The summary again from the stored plans, none run: the same summary, the table untouched.
    stored = (tmp_path / "scaling.jsonl").read_bytes()
    (tmp_path / "scaling.json").unlink()
    assert cli_main([*args, "--tables-only"]) == 0
    again = json.loads((tmp_path / "scaling.json").read_text())
    assert (tmp_path / "scaling.jsonl").read_bytes() == stored
    assert again["headline"] == summary["headline"] and again["sweeps"] == summary["sweeps"]
    assert again["scale"] == summary["scale"]
    assert again["tables_only"] and again["runs"][0]["commit"] == summary["provenance"]["commit"]
    # With the run's own summary still there, its machine and provenance are kept.
    (tmp_path / "scaling.json").write_text(json.dumps(summary))
    assert cli_main([*args, "--tables-only"]) == 0
    kept = json.loads((tmp_path / "scaling.json").read_text())
    assert kept["machine"] == summary["machine"] and kept["provenance"] == summary["provenance"]
    assert kept["written_by"]["commit"] == summary["provenance"]["commit"]


def test_one_plan_is_measured_in_process() -> None:
    sc = scaling_scenario(30, 40, 2, seed=0)
    gated = time_plan(sc, "kalman", "auto", 5)
    # The initial E-step and one per iteration, read from the plan's history; dense ones never gate.
    assert gated["estep_calls"] == 6 and 0 <= gated["estep_gated_calls"] <= 6
    assert time_plan(sc, "kalman", "off", 5)["estep_gated_calls"] == 0
    assert gated["peak_rss_mib"] >= gated["base_rss_mib"] > 0
    agree = agreement(sc, "kalman", 5)
    assert agree["assignment_equal"] and agree["estep_map_equal"]
    assert agree["estep_W_rel"] < 1e-12


def test_fit_slope() -> None:
    assert math.isclose(fit_slope([1, 2, 4], [3, 12, 48]), 2.0)
    assert math.isnan(fit_slope([1], [1])) and math.isnan(fit_slope([2, 2], [1, 3]))
