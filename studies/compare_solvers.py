"""Study 2: M-step backends (osqp, clarabel, kalman, cvxpy with each installed solver) against the
kalman reference; writes studies/results/solvers/ (solvers.md, solvers.png, CSV and JSON).

    python studies/compare_solvers.py [--fresh] [--workers 1]
"""

import argparse
from pathlib import Path

from pmht_opt.studies import solvers
from pmht_opt.studies.common import executor_from_args

HERE = Path(__file__).resolve().parent

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
            command="python studies/compare_solvers.py --fresh",
        )
