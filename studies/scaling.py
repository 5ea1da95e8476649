"""Study 3: plan time and peak memory as N, T and M grow, with the gated E-step against the dense one;
writes studies/results/scaling/ (scaling.csv, scaling.json, scaling.md, scaling.png).

    python studies/scaling.py [--reps 3] [--backends kalman clarabel osqp] [--quick] [--fresh]
"""

import argparse
import sys
from pathlib import Path

# Python puts this script's directory first on the path, where studies/solvers.py would shadow the
# top-level ``solvers`` package the library imports: look it up from the repository root instead.
HERE = Path(__file__).resolve().parent
sys.path[:] = [p for p in sys.path if Path(p or ".").resolve() != HERE]
sys.path.insert(0, str(HERE.parent))

from pmht_opt.studies import scaling  # noqa: E402

if __name__ == "__main__":
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--fresh", action="store_true", help="start the results table afresh (default: resume)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    scaling.add_arguments(p)
    a = p.parse_args()
    a.out = HERE / "results" / "scaling"
    raise SystemExit(scaling.main(a))
