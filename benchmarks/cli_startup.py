"""Start-up time of ``indoormap`` commands: each command's module imported when it runs
(``survey.cli.COMMANDS``) against every command's module imported first (how the CLI started
before session 41), in the same run.

    python benchmarks/cli_startup.py [--repeats N]

Each row runs ``indoormap ARGS`` in a fresh interpreter (what a user waits for, Python's own
start included) and prints the median wall time of N runs (default 5) of both ways and their
ratio. The baseline imports every module of ``COMMANDS`` before running the same arguments.
The machine's load average is printed, since other processes slow both alike.

Measured when the command table became lazy (2-core machine, load average 0.2):

    indoormap ...           all first     lazy   ratio
    --help                       1.49     0.07   22.1x
    --version                    1.49     0.06   22.9x
    bundle --help                1.32     0.14    9.4x
    localize --help              1.33     0.16    8.2x
    validate --help              1.43     0.15    9.4x
    build --help                 1.41     1.42    1.0x
    ingest --help                1.53     0.66    2.3x

``build`` needs the survey and mapping stages (pandas, scipy, numba), so it gains nothing;
``localize`` and ``validate`` load those when their walks are read, not to start.
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import time

ROWS = [["--help"], ["--version"], ["bundle", "--help"], ["localize", "--help"],
        ["validate", "--help"], ["build", "--help"], ["ingest", "--help"]]


def _code(args: list[str], eager: bool) -> str:
    first = ("from survey.cli import COMMANDS\nimport importlib\n"
             "for m, _, _ in COMMANDS.values():\n    importlib.import_module(m)\n") if eager else ""
    return (first + "from survey.cli import main\nimport contextlib, io\n"
            "with contextlib.redirect_stdout(io.StringIO()):\n"
            f"    try:\n        main({args!r})\n    except SystemExit:\n        pass\n")


def _wall_s(code: str, repeats: int) -> float:
    """Median wall seconds of ``python -c CODE`` over ``repeats`` fresh interpreters."""
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        subprocess.run([sys.executable, "-c", code], check=True)
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeats", type=int, default=5)
    args = ap.parse_args()
    print(f"load average {os.getloadavg()[0]:.1f}; median of {args.repeats} runs, seconds")
    print(f"{'indoormap ...':<22} {'all first':>10} {'lazy':>8} {'ratio':>7}")
    for row in ROWS:
        eager = _wall_s(_code(row, eager=True), args.repeats)
        lazy = _wall_s(_code(row, eager=False), args.repeats)
        print(f"{' '.join(row):<22} {eager:>10.2f} {lazy:>8.2f} {eager / lazy:>6.1f}x")


if __name__ == "__main__":
    main()
