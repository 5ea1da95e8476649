"""``pmht-opt study scaling --quick`` writes its tables, figure and agreement figures."""

from __future__ import annotations

import json
from pathlib import Path

from pmht_opt.cli import main as cli_main


def test_scaling_study_quick(tmp_path: Path) -> None:
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
    assert cli_main(["study", "scaling", "--quick", "--reps", "0", "--out", str(tmp_path), "--quiet"]) == 2
