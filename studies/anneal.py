"""Plain against annealed EM on scenarios A, B, C (issue 5); writes studies/results/anneal*.

    python studies/anneal.py [--trials 100] [--workers 2]
"""

import argparse
from pathlib import Path

from pmht_opt.studies import anneal

if __name__ == "__main__":
    p = argparse.ArgumentParser(description=__doc__)
    p.add_argument("--trials", type=int, default=100)
    p.add_argument("--workers", type=int, default=2)
    a = p.parse_args()
    anneal.run(Path(__file__).parent / "results", trials=a.trials, workers=a.workers)
