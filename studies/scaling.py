"""Study 3: plan time and peak memory as N, T and M grow, with the gated E-step against the dense one;
writes studies/results/scaling/ (scaling.csv, scaling.json, scaling.md, scaling.png).

    python studies/scaling.py [--reps 3] [--backends kalman clarabel osqp] [--quick] [--fresh]
"""

import argparse
from pathlib import Path

from pmht_opt.studies import scaling

HERE = Path(__file__).resolve().parent

if __name__ == "__main__":
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--fresh", action="store_true", help="start the results table afresh (default: resume)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    scaling.add_arguments(p)
    a = p.parse_args()
    a.out = HERE / "results" / "scaling"
    raise SystemExit(scaling.main(a))
