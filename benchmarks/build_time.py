"""Time to build a floor's map bundle from raw traces, and whether rebuilding is byte-identical.

    python benchmarks/build_time.py [FLOOR_DIR]

Default ``../shared/ilc/site1/F1`` (skips without it; pass ``data/sample_site/F1`` for the
sample, after ``indoormap simulate data/sample_site``). Runs ``indoormap build FLOOR_DIR -o
OUT`` twice in fresh processes (ingest, process, level, interpolate, write) and prints the
wall time of each and whether the two bundles have identical bytes. The target for site1/F1
on this 2-core machine is under 60 s.
"""

from __future__ import annotations

import argparse
import filecmp
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from real_data import ILC_SITE1  # $INDOORMAP_ILC or ../shared/ilc

DEFAULT = ILC_SITE1 / "F1"


def same_tree(a: Path, b: Path) -> bool:
    files_a = sorted(p.relative_to(a) for p in a.rglob("*") if p.is_file())
    files_b = sorted(p.relative_to(b) for p in b.rglob("*") if p.is_file())
    return files_a == files_b and all(filecmp.cmp(a / f, b / f, shallow=False)
                                      for f in files_a)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("floor", nargs="?", type=Path, default=DEFAULT, metavar="FLOOR_DIR",
                    help=f"a floor folder (default {DEFAULT})")
    floor = ap.parse_args().floor
    if not (floor / "path_data_files").is_dir():
        print(f"skipped: {floor} not available")
        return 0
    with tempfile.TemporaryDirectory() as tmp:
        outs, times = [], []
        for k in range(2):
            out = Path(tmp) / f"out{k}"
            t = time.perf_counter()
            subprocess.run([sys.executable, "-m", "survey.cli", "build", str(floor), "-o",
                            str(out)], check=True, capture_output=True)
            times.append(time.perf_counter() - t)
            outs.append(out / floor.name)
        n = len(list((floor / "path_data_files").iterdir()))
        print(f"{'build':<40} {'seconds':>8}")
        for k, s in enumerate(times):
            print(f"{f'indoormap build {floor.name} ({n} traces), run {k + 1}':<40} {s:8.1f}")
        print(f"byte-identical bundles: {same_tree(outs[0], outs[1])}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
