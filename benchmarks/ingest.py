"""Ingest throughput: indoormap's reader against a plain line-by-line Python reader.

    python benchmarks/ingest.py [FOLDER ...] [--repeat 3]

Default input: ``../shared/ilc/site1/F1`` when present, else the simulated sample in
``data/sample_site`` (simulated there when missing). Every measurement runs in a fresh subprocess (so peak memory is its own),
on the same files, in this one run; the table reports MB/s of trace text (after gunzip), the
ratio to the plain reader, and peak resident memory. Best of ``--repeat`` runs.

Measured on this 2-core machine (site1/F1, 106 traces, 179.5 MB of text)::

    reader                                               s     MB/s  x plain  peak MB
    plain line-by-line Python reader (baseline)      10.18     17.6     1.00       28
    indoormap reader, 1 process                       1.53    117.2     6.65      449
    indoormap ingest to store, 1 process              3.03     59.2     3.36      441
    indoormap ingest to store, 2 workers              4.57     39.3     2.23      423

The reader already keeps both cores busy (a read-ahead thread inflating, a worker thread
scanning the next batch while the main thread builds tables). Ingest adds one Parquet part per
stream and trace, fsynced (about 1.5 s here). Two worker processes are slower on one floor:
each spawned worker first imports numpy/pandas/pyarrow/numba (about 2 s); they pay off only on
inputs several times larger.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path

from real_data import ILC_SITE1, REPO  # $INDOORMAP_ILC or ../shared/ilc

SHARED_F1 = ILC_SITE1 / "F1"

CHILD = r"""
import json, resource, sys, time, gzip
sys.path.insert(0, {bench!r})
paths = json.loads(sys.argv[1]); mode = sys.argv[2]; out = sys.argv[3]
# Imports (and numba's cached machine code) load before the clock starts, in every mode.
from plain_reader import read_plain
if mode != "plain":
    from survey.ingest import ingest
    from survey.trace_reader import iter_traces, parse_trace_bytes
    parse_trace_bytes(b"1\tTYPE_ACCELEROMETER\t1.5\t2\t3\t3\n"
                      b"2\tTYPE_WIFI\tap\tAA:BB:CC:DD:EE:FF\t-50\t2412\t1\n")
t = time.perf_counter()
if mode == "plain":
    for p in paths:
        read_plain(p)
elif mode == "reader":
    for _ in iter_traces(paths):
        pass
elif mode == "ingest-1":
    ingest(paths, out, workers=1)
elif mode == "ingest-2":
    ingest(paths, out, workers=2)
dt = time.perf_counter() - t
rss = max(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss,
          resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss)
print(json.dumps({{"seconds": dt, "peak_rss_mb": rss / 1024}}))
"""

MODES = [
    ("plain", "plain line-by-line Python reader (baseline)"),
    ("reader", "indoormap reader, 1 process"),
    ("ingest-1", "indoormap ingest to store, 1 process"),
    ("ingest-2", "indoormap ingest to store, 2 workers"),
]


def text_bytes(paths: list[str]) -> int:
    import gzip

    total = 0
    for p in paths:
        opener = gzip.open if p.endswith(".gz") else open
        with opener(p, "rb") as fh:
            total += len(fh.read())
    return total


def run(mode: str, paths: list[str]) -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        code = CHILD.format(bench=str(Path(__file__).parent))
        proc = subprocess.run([sys.executable, "-c", code, json.dumps(paths), mode,
                               str(Path(tmp) / "store")], capture_output=True, text=True,
                              check=True, cwd=REPO)
    return json.loads(proc.stdout.strip().splitlines()[-1])


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("folders", nargs="*")
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()
    folders = [Path(f) for f in args.folders]
    if not folders:
        if SHARED_F1.exists():
            folders = [SHARED_F1]
        else:
            from survey.sim.site import ensure_sample_site

            folders = [ensure_sample_site(REPO / "data" / "sample_site")]
    paths = sorted(str(p) for f in folders for p in f.rglob("*")
                   if p.name.endswith((".txt", ".txt.gz")))
    if not paths:
        print("no trace files found; nothing to measure")
        return 0
    size = text_bytes(paths)
    print(f"input: {len(paths)} traces, {size / 1e6:.1f} MB of text "
          f"({sum(Path(p).stat().st_size for p in paths) / 1e6:.1f} MB on disk) from "
          f"{', '.join(map(str, folders))}")
    rows = []
    base = None
    for mode, label in MODES:
        best = min((run(mode, paths) for _ in range(args.repeat)), key=lambda r: r["seconds"])
        mbps = size / 1e6 / best["seconds"]
        base = base or mbps
        rows.append((label, best["seconds"], mbps, mbps / base, best["peak_rss_mb"]))
    print(f"{'reader':<46} {'s':>7} {'MB/s':>8} {'x plain':>8} {'peak MB':>8}")
    for label, s, mbps, ratio, rss in rows:
        print(f"{label:<46} {s:7.2f} {mbps:8.1f} {ratio:8.2f} {rss:8.0f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
