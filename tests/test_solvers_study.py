"""Study 2 (``pmht-opt study solvers``): the quick run writes its files, and the numbers behave."""

from __future__ import annotations

import json
import math
from pathlib import Path

from pmht_opt.cli import main
from studies.compare_solvers import MSTEPS, PLANS
from studies.store import read_rows


def test_quick_solvers_study(tmp_path: Path) -> None:
    assert main(["study", "solvers", "--quick", "--out", str(tmp_path), "--quiet"]) == 0
    for name in ("solvers.md", "solvers.png", "solvers.json", "solvers_msteps.jsonl", "solvers_plans.jsonl"):
        assert (tmp_path / name).stat().st_size > 0, name
    assert (tmp_path / "solvers.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"

    rows = read_rows(tmp_path / "solvers_msteps.jsonl", MSTEPS, "solvers_msteps")
    unc = [r for r in rows if r["part"] == "unconstrained"]
    assert {r["case"] for r in unc} == {"unconstrained-early", "unconstrained-late"}
    for r in unc:
        if r["backend"] == "kalman":
            assert r["status"] == "optimal" and r["max_pos_diff"] == 0.0
        if r["backend"] in ("clarabel", "osqp"):
            # The QP backends solve the same M-step as the RTS smoother, to solver precision.
            assert r["status"] == "optimal", r
            assert r["max_pos_diff"] < 1e-6, r
            assert abs(r["objective_gap"]) < 1e-9, r
            assert r["iterations"] > 0 and r["time_s"] > 0
        # Every row has a status; a failed or n/a one says why and has no measurement.
        assert r["status"] in ("optimal", "inaccurate", "failed", "infeasible", "n/a")
        if r["status"] in ("failed", "n/a"):
            assert r["message"] and not math.isfinite(r["max_pos_diff"])

    con = [r for r in rows if r["part"] == "constrained"]
    by = {(r["case"], r["backend"]): r for r in con}
    for case in ("speed+area", "obstacle"):
        assert by[(case, "kalman")]["status"] == "n/a"
        ref = by[(case, "reference (cones)")]
        assert ref["status"] == "optimal" and ref["max_pos_diff"] == 0.0
        clar = by[(case, "clarabel")]
        assert clar["status"] == "optimal" and clar["max_violation"] < 1e-6
        assert abs(clar["objective_gap"]) < 1e-8
        # OSQP solves the polygonal problem: compared with its exact solve it is close; its gap to the
        # conic reference is never negative beyond tolerance (an inner polygon cannot do better).
        osqp = by[(case, "osqp")]
        assert osqp["status"] == "optimal" and osqp["conic"] is False
        assert osqp["max_pos_diff_same"] < 1e-2
        assert osqp["objective_gap"] > -1e-6

    plans = read_rows(tmp_path / "solvers_plans.jsonl", PLANS.schema, PLANS.name)
    kinds = {r["backend"]: r for r in plans}
    assert kinds["kalman"]["status"] == "optimal" and kinds["kalman"]["max_pos_diff"] == 0.0
    assert kinds["clarabel"]["status"] == "optimal" and kinds["clarabel"]["max_pos_diff"] < 1e-4
    assert kinds["osqp"]["iterations_done"] == 10

    summary = json.loads((tmp_path / "solvers.json").read_text())
    assert {s["backend"] for s in summary["plans"]} >= {"kalman", "clarabel", "osqp"}
    text = (tmp_path / "solvers.md").read_text()
    assert "Reference: the kalman (RTS) smoother" in text
    assert "Kalman cannot take constraints: the reference is Clarabel" in text

    # The tables again from the raw tables alone: the same text.
    (tmp_path / "solvers.md").unlink()
    assert main(["study", "solvers", "--out", str(tmp_path), "--tables-only", "--quiet"]) == 0
    assert (tmp_path / "solvers.md").read_text() == text
