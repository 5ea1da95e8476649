"""Study 2: M-step backends (osqp, clarabel, kalman, cvxpy with each installed solver) against the
kalman reference; writes studies/results/solvers/ (solvers.md, solvers.png, CSV and JSON).

    python studies/solvers.py [--fresh] [--workers 1]
"""

import argparse
import sys
from pathlib import Path

# Python puts this script's directory first on the path, where this file would shadow the top-level
# ``solvers`` package the library imports: look it up from the repository root instead.
HERE = Path(__file__).resolve().parent
sys.path[:] = [p for p in sys.path if Path(p or ".").resolve() != HERE]
sys.path.insert(0, str(HERE.parent))

from pmht_opt.studies import solvers  # noqa: E402
from pmht_opt.studies.common import executor_from_args  # noqa: E402

if __name__ == "__main__":
    p = argparse.ArgumentParser(description=__doc__)
    p.add_argument("--workers", type=int, default=1, help="processes for the whole plans (1: clean timings)")
    p.add_argument("--fresh", action="store_true", help="re-run the whole plans instead of resuming")
    p.add_argument("--quiet", action="store_true")
    a = p.parse_args()
    with executor_from_args(a) as ex:
        solvers.run(
            HERE / "results" / "solvers",
            executor=ex,
            progress=not a.quiet,
            resume=not a.fresh,
            command="python studies/solvers.py --fresh",
        )
