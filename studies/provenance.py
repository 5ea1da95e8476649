"""Where a result came from: the one record every results file of the studies carries.

A measured number means little without the code that produced it (commit, and whether the tree had
uncommitted changes), the library versions (solver releases change iterations and digits), and the
machine and its load at the time (other work inflates every timing alike).
"""

from __future__ import annotations

import datetime
import importlib.metadata
import os
import platform
import subprocess
import sys
from pathlib import Path
from typing import Any

#: Distributions whose versions are recorded (those absent are left out).
PACKAGES = (
    "pmht-opt",
    "numpy",
    "scipy",
    "cvxpy",
    "osqp",
    "clarabel",
    "pyvrp",
    "scs",
    "highspy",
    "ortools",
    "pandas",
    "dask",
    "distributed",
)

_REPO = Path(__file__).resolve().parent.parent


def package_versions(names: tuple[str, ...] = PACKAGES) -> dict[str, str]:
    """Installed versions of ``names`` (distribution name -> version), the missing ones left out."""
    out: dict[str, str] = {}
    for name in names:
        try:
            out[name] = importlib.metadata.version(name)
        except importlib.metadata.PackageNotFoundError:
            continue
    return out


def _git(*args: str) -> str | None:
    try:
        done = subprocess.run(
            ["git", *args], cwd=_REPO, capture_output=True, text=True, timeout=10, check=True
        )
    except (OSError, subprocess.SubprocessError):
        return None
    return done.stdout.strip()


def load_average() -> float | None:
    """The 1-minute load average, or ``None`` where the platform has none."""
    try:
        return round(os.getloadavg()[0], 2)
    except (AttributeError, OSError):
        return None


def provenance() -> dict[str, Any]:
    """Commit, dirty flag, package versions, Python, machine, CPU count, load average, date and command.

    ``commit`` and ``dirty`` are ``None`` outside a git checkout (an installed copy of the studies).
    ``dirty`` says whether tracked files other than the committed results (``studies/results/``, which
    a running study rewrites) differ from the commit: whether the code that ran is the commit's.
    """
    commit = _git("rev-parse", "HEAD")
    status = (
        _git("status", "--porcelain", "--untracked-files=no", "--", ".", ":(exclude)studies/results")
        if commit
        else None
    )
    return {
        "commit": commit or None,
        "dirty": None if status is None else bool(status),
        "packages": package_versions(),
        "python": platform.python_version(),
        "implementation": platform.python_implementation(),
        "platform": platform.platform(),
        "machine": platform.machine(),
        "cpu_count": os.cpu_count(),
        "load_average": load_average(),
        "date": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
        "command": " ".join([Path(sys.argv[0]).name, *sys.argv[1:]]) if sys.argv and sys.argv[0] else "",
    }
