"""Long fuzz run of the survey parsers (issue 8, item 1). What is checked: ``tests/fuzzing.py``.

    python benchmarks/fuzz_parsers.py                      # 5 minutes, seeds 1, 2, ...
    python benchmarks/fuzz_parsers.py --minutes 30 --seed 100
    python benchmarks/fuzz_parsers.py --examples 20000 --save tests/data/corrupt

Runs seeded rounds (seed, seed + 1, ...) until the time budget or the number of mutated inputs
is used up. Each round mutates real-format trace texts (windows of ``data/sample_site`` and
factory traces; parsed in mixed batches, alone, lenient and strict), damaged gzip files (read,
batched and ingested into a scratch store) and walk plans / sensor CSVs. Prints how many inputs
were tried and how many failed, per kind, and one example of each kind of failure. With
``--save DIR`` one minimized input per kind of failure goes to DIR (``tests/data/corrupt`` is
replayed by the normal test run). Exit status 1 if any input failed.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "tests"))

from fuzzing import FuzzStats, run_fuzz, save_failures

#: Mutated inputs per round: trace texts, gzip files, walk-line files.
ROUND = {"texts": 400, "gz_cases": 60, "walk_cases": 200}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--minutes", type=float, default=5.0, help="time budget (default 5)")
    ap.add_argument("--examples", type=int, default=None,
                    help="stop after this many mutated inputs (default: time budget only)")
    ap.add_argument("--seed", type=int, default=1, help="seed of the first round")
    ap.add_argument("--save", type=Path, default=None,
                    help="write one minimized input per kind of failure here")
    args = ap.parse_args(argv)

    deadline = time.monotonic() + 60 * args.minutes
    total = FuzzStats({"text": 0, "gzip": 0, "walkline": 0}, [])
    seed = args.seed
    start = time.monotonic()
    with tempfile.TemporaryDirectory(prefix="indoormap-fuzz-") as tmp:
        while time.monotonic() < deadline and (args.examples is None
                                               or total.total < args.examples):
            stats = run_fuzz(seed, Path(tmp) / f"round{seed}", **ROUND, compare_all=True,
                             full_traces=1, deadline=deadline)
            for k, v in stats.tried.items():
                total.tried[k] += v
            total.failures += stats.failures
            print(f"round seed={seed}: {stats.total} inputs {stats.tried}, "
                  f"{len(stats.failures)} failed, {stats.seconds:.0f} s", flush=True)
            seed += 1
        elapsed = time.monotonic() - start
        print(f"\nseeds {args.seed}..{seed - 1}: {total.total} mutated inputs tried "
              f"({', '.join(f'{k} {v}' for k, v in total.tried.items())}) in {elapsed:.0f} s; "
              f"{len(total.failures)} failed")
        for (kind, sig), failures in sorted(total.by_signature().items()):
            print(f"  {len(failures):5d} x {kind} {sig}: {failures[0].problems[0][:200]}")
        if args.save and total.failures:
            for path in save_failures(total, args.save, Path(tmp) / "save"):
                print(f"saved {path}")
    return 1 if total.failures else 0


if __name__ == "__main__":
    sys.exit(main())
