"""Benchmark: the cost of the trial machinery itself, on trials that do no work.

Runs ``N`` trivial trials (``{"square": seed * seed}``) through :func:`studies.trials.run_trials` inline
into a fresh results file, for N = 10,000 and 20,000, several times each, and prints the median. Every
trial is validated, appended, flushed and counted by the progress bar exactly as in a real study, so
this is the overhead a study pays per trial; it must not grow with the number of trials already
recorded (the second size should take about twice as long as the first). Target: 10,000 trials under
10 s on the project's 2-core machine. Writes ``studies/results/bench_trials.json`` with provenance.

    python studies/bench_trials.py [--repeats 5] [--sizes 10000 20000]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from studies.report import median, write_json
from studies.trials import TrialTable, run_trials

TARGET_S = 10.0


def square(seed: int) -> dict[str, Any]:
    """A trial that does nothing but return a result."""
    return {"square": seed * seed}


TABLE = TrialTable.of("bench", square, {"square": "int"})


def time_trials(n: int, progress: bool) -> float:
    """Seconds to run ``n`` trivial trials inline into a new results file (a fresh directory)."""
    with tempfile.TemporaryDirectory() as tmp:
        started = time.perf_counter()
        rows = run_trials(TABLE, [{"seed": s} for s in range(n)], Path(tmp), progress=progress)
        elapsed = time.perf_counter() - started
    if len(rows) != n or rows[-1]["square"] != (n - 1) ** 2:
        raise RuntimeError("the benchmark's rows are wrong")
    return elapsed


def main(argv: list[str] | None = None) -> int:
    """Time each size ``--repeats`` times, print the medians, write the JSON."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0] if __doc__ else None)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--sizes", type=int, nargs="+", default=[10_000, 20_000])
    parser.add_argument(
        "--quiet", action="store_true", help="no progress bar (shown by default, as in a study)"
    )
    parser.add_argument("--out", type=Path, default=Path(__file__).parent / "results" / "bench_trials.json")
    args = parser.parse_args(argv)
    results: dict[str, dict[str, Any]] = {}
    for n in args.sizes:
        runs = [time_trials(n, not args.quiet) for _ in range(max(args.repeats, 1))]
        results[str(n)] = {
            "median_s": median(runs),
            "runs_s": [round(r, 4) for r in runs],
            "per_trial_us": 1e6 * median(runs) / n,
        }
        each = 1e6 * median(runs) / n
        print(f"{n:>7} trivial trials inline: median {median(runs):.3f} s ({each:.1f} us each)")
    first, last = args.sizes[0], args.sizes[-1]
    ratio = results[str(last)]["median_s"] / results[str(first)]["median_s"]
    print(f"ratio {last} / {first}: {ratio:.2f} (linear: {last / first:.2f})")
    payload = {
        "benchmark": "trivial trials through studies.trials.run_trials, inline, into a fresh JSON Lines file"
        + ("" if args.quiet else ", with the progress bar"),
        "repeats": args.repeats,
        "target_s": {"10000": TARGET_S},
        "results": results,
        "ratio": ratio,
    }
    print(f"wrote: {write_json(args.out, payload)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
