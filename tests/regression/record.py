"""Record the plans the regression test compares against (``tests/regression/plans.npz``).

Run from the repository root at the commit whose behaviour is the reference::

    python tests/regression/record.py

Every case uses public API only, so the same script runs before and after a redesign. A deliberate
change of behaviour re-records the file in its own commit, with the reason in ``docs/decisions.md``.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

from cases import CASES, run_case  # noqa: E402


def environment(commit: str) -> dict[str, Any]:
    """The machine, packages and BLAS the reference plans were recorded with."""
    sys.path.insert(0, str(HERE.parent.parent))
    from studies.provenance import provenance

    info = provenance()
    info["commit"] = commit
    config = np.show_config(mode="dicts")
    blas = config.get("Build Dependencies", {}).get("blas", {})
    info["blas"] = {k: blas.get(k) for k in ("name", "version", "openblas configuration")}
    info["cpu"] = config.get("SIMD Extensions", {})
    return info


def main() -> None:
    arrays: dict[str, np.ndarray] = {}
    for name in CASES:
        out = run_case(name)
        for key, value in out.items():
            arrays[f"{name}/{key}"] = np.asarray(value)
        print(name, {k: np.asarray(v).shape for k, v in out.items()}, flush=True)
    commit = subprocess.run(
        ["git", "rev-parse", "HEAD"], capture_output=True, text=True, check=False, cwd=HERE
    ).stdout.strip()
    arrays["commit"] = np.asarray(commit)
    env = environment(commit)  # before writing: the checkout's state as the plans were made
    np.savez_compressed(HERE / "plans.npz", **arrays)
    (HERE / "environment.json").write_text(json.dumps(env, indent=2) + "\n")
    print(f"wrote {HERE / 'plans.npz'} and environment.json ({len(CASES)} cases, commit {commit})")


if __name__ == "__main__":
    main()
