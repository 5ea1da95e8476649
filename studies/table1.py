"""The paper's Table 1 and Figures 1-5 with what the paper lacked (issue 6); writes studies/results/table1/.

    python studies/table1.py [--trials 100] [--workers 2]

Equivalent to ``pmht-opt study table1 --out studies/results/table1``. Resumes an interrupted run.
"""

import argparse
from pathlib import Path

from pmht_opt.studies import table1

if __name__ == "__main__":
    p = argparse.ArgumentParser(description=__doc__)
    p.add_argument("--trials", type=int, default=100)
    p.add_argument("--workers", type=int, default=2)
    a = p.parse_args()
    table1.run(Path(__file__).parent / "results" / "table1", trials=a.trials, workers=a.workers)
