r"""Peak resident memory (and wall time) of ``indoormap build`` on a real floor and on N x copies.

    python benchmarks/build_memory.py [FLOOR_DIR] [--scale 1,10] [--limit-minutes 60]
                                      [--limit-gb 16]

Default FLOOR_DIR ``../shared/ilc/site1/F1`` (the largest real floor: 106 traces, 180 MB of
text); skips with exit 0 without it. Scale 1 builds the floor as is. Scale N > 1 builds a
temporary floor (in a tempdir) with the same floor_info.json and geojson_map.json and N copies of
every trace: each copy gets its own file name (the trace id is the file name, see
``survey.trace_reader.trace_id_from_path``) and its own bytes (an extra ``#\tBenchmarkCopy:k``
header line, which the header parser keeps as an unknown key), so ingest's sha256 de-duplication
keeps all of them; after the build the store catalog is checked to hold N x the traces.

Each build is ``python -m survey.cli build FLOOR -o OUT --store STORE`` in a fresh process. Peak
RSS is that child's ``ru_maxrss`` (from ``os.wait4``); its RSS is also sampled from /proc every
0.5 s and matched to the build's progress lines to name the phase at the peak. A build running
longer than ``--limit-minutes`` or above ``--limit-gb`` is killed and reported as such.

Measured on this 2-core machine, 24 GB RAM (site1/F1; docs/reliability.md, "Resource
limits")::

    scale  traces  text MB  wall s  peak RSS MB  last progress line before the peak
        1     106      180    27.5          570  site: bundle ... (the end of the build)
       10    1060     1795   295.0          689  F1: 1060 walks
    peak RSS 10x / 1x: 1.21

(Session 2: 898 and 4713 MB, 5.25x; session 3, walk-by-walk reads: 641 and 2129 MB, 3.32x;
session 4, radio steps on integer codes: 623 and 1781 MB, 2.86x; session 5, magnetic layers
walk by walk: 554 and 1206 MB, 2.18x.) Session 6: the radio maps are reduced walk by walk too
(``mapping.radio_reduce``; the radio part alone peaks at 405 MB on site1/F1 and 485 MB on the
10x floor), so memory no longer grows with the survey; the 10x peak varies between runs
(662-736 MB) with the heap left by the earlier phases.
In the 10x floor every walk has nine exact copies, so the radio steps keep more transmitters
(no longer "rare") and the kernel bandwidth cross-validation picks 0.5 m instead of 3.0 m:
the bundle is not a realistic one, only the memory and time are.
"""

from __future__ import annotations

import argparse
import os
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

from real_data import ILC_SITE1, REPO  # $INDOORMAP_ILC or ../shared/ilc

DEFAULT = ILC_SITE1 / "F1"
sys.path.insert(0, str(REPO))

from survey.trace_bytes import read_trace_bytes
from survey.trace_reader import find_trace_files, trace_id_from_path

SAMPLE_S = 0.5


def make_scaled_floor(src: Path, dst: Path, n: int) -> tuple[int, int]:
    """Floor folder ``dst`` with ``n`` distinct copies of every trace of ``src``.

    Returns (traces written, bytes of text)."""
    import gzip

    dst.mkdir(parents=True)
    for name in ("floor_info.json", "geojson_map.json"):
        if (src / name).exists():
            shutil.copyfile(src / name, dst / name)
    out = dst / "path_data_files"
    out.mkdir()
    count = text = 0
    for path in find_trace_files([src / "path_data_files"]):
        data, _ = read_trace_bytes(path)
        tid = trace_id_from_path(path)
        # after the first line when it is a header line, else at the top
        cut = data.index(b"\n") + 1 if data.startswith(b"#") and b"\n" in data else 0
        for k in range(n):
            copy = data[:cut] + f"#\tBenchmarkCopy:{k}\n".encode() + data[cut:]
            (out / f"{tid}_x{k:03d}.txt.gz").write_bytes(gzip.compress(copy, compresslevel=1))
            count += 1
            text += len(copy)
    return count, text


def floor_text(floor: Path) -> tuple[int, int]:
    files = find_trace_files([floor / "path_data_files"])
    return len(files), sum(len(read_trace_bytes(p)[0]) for p in files)


def proc_rss_mb(pid: int) -> float | None:
    try:
        with open(f"/proc/{pid}/status") as fh:
            for line in fh:
                if line.startswith("VmRSS:"):
                    return int(line.split()[1]) / 1024
    except OSError:
        return None
    return None


def run_build(floor: Path, work: Path, limit_s: float, limit_mb: float, log) -> dict:
    """Build ``floor`` in a fresh process; wall time, peak RSS, phase at peak, status."""
    out, store = work / "out", work / "store"
    cmd = [sys.executable, "-m", "survey.cli", "build", str(floor), "-o", str(out),
           "--store", str(store)]
    log(f"$ {' '.join(cmd)}")
    lines: list[tuple[float, str]] = []  # (seconds since start, progress/output line)
    t0 = time.perf_counter()
    proc = subprocess.Popen(cmd, cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                            text=True)

    def reader() -> None:
        for line in proc.stdout:
            line = line.rstrip()
            lines.append((time.perf_counter() - t0, line))
            log(f"  [{time.perf_counter() - t0:7.1f} s] {line}")

    th = threading.Thread(target=reader, daemon=True)
    th.start()
    samples: list[tuple[float, float]] = []
    status = "ok"
    last_report = 0.0
    while True:
        pid, wstatus, usage = os.wait4(proc.pid, os.WNOHANG)
        if pid:
            break
        now = time.perf_counter() - t0
        rss = proc_rss_mb(proc.pid)
        if rss is not None:
            samples.append((now, rss))
            if now - last_report >= 60:
                last_report = now
                log(f"  [{now:7.1f} s] rss {rss:.0f} MB (max so far "
                    f"{max(s[1] for s in samples):.0f} MB)")
            if status == "ok" and (now > limit_s or rss > limit_mb):
                status = (f"stopped after {now:.0f} s" if now > limit_s
                          else f"stopped at {rss:.0f} MB")
                log(f"  {status}; last progress line: {lines[-1][1] if lines else '-'}")
                proc.send_signal(signal.SIGKILL)
        time.sleep(SAMPLE_S)
    wall = time.perf_counter() - t0
    proc.returncode = os.waitstatus_to_exitcode(wstatus)
    th.join(timeout=5)
    if status == "ok" and proc.returncode != 0:
        status = f"failed (exit {proc.returncode})"
    peak = usage.ru_maxrss / 1024  # KiB on Linux
    phase, t_peak = "-", None
    if samples:
        t_peak, _ = max(samples, key=lambda s: s[1])
        before = [ln for t, ln in lines if t <= t_peak and not ln.startswith("  ")]
        phase = before[-1] if before else "start"
    walks = None
    for _, ln in lines:
        m = re.search(r"\((\d+) walks;", ln)
        if m:
            walks = int(m.group(1))
    n_cat = None
    if (store / "catalog.parquet").exists():
        from survey.store import SurveyStore

        n_cat = len(SurveyStore.open(store).catalog())
    return {"wall": wall, "peak_mb": peak, "status": status, "phase": phase, "t_peak": t_peak,
            "walks": walks, "catalog": n_cat, "samples": samples, "lines": lines}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("floor", nargs="?", type=Path, default=DEFAULT)
    ap.add_argument("--scale", default="1,10", help="comma-separated copy counts (default 1,10)")
    ap.add_argument("--limit-minutes", type=float, default=60.0)
    ap.add_argument("--limit-gb", type=float, default=16.0)
    args = ap.parse_args()
    floor = args.floor.resolve()
    if not (floor / "path_data_files").is_dir() or not (floor / "geojson_map.json").exists():
        print(f"skipped: {floor} not available")
        return 0
    scales = [int(s) for s in args.scale.split(",") if s.strip()]

    def log(msg: str) -> None:
        print(msg, flush=True)

    rows = []
    for n in scales:
        with tempfile.TemporaryDirectory(prefix="indoormap-buildmem-") as tmp:
            tmp = Path(tmp)
            if n == 1:
                target = floor
                traces, text = floor_text(floor)
            else:
                target = tmp / "floor" / floor.name  # same folder name: same floor id
                t = time.perf_counter()
                traces, text = make_scaled_floor(floor, target, n)
                log(f"scale {n}: wrote {traces} traces ({text / 1e6:.0f} MB of text) to "
                    f"{target} in {time.perf_counter() - t:.0f} s")
            log(f"scale {n}: building {traces} traces")
            r = run_build(target, tmp, args.limit_minutes * 60, args.limit_gb * 1024, log)
            if r["catalog"] is not None and r["catalog"] != traces:
                r["status"] += f"; catalog holds {r['catalog']} of {traces} traces"
            log(f"scale {n}: {r['status']}, {r['wall']:.1f} s, peak RSS {r['peak_mb']:.0f} MB "
                f"(sampled peak at {r['t_peak'] or 0:.0f} s in '{r['phase']}'), catalog "
                f"{r['catalog']} traces, bundle {r['walks']} walks")
            rows.append((n, traces, text, r))

    print()
    print(f"floor: {floor}")
    print(f"{'scale':>5} {'traces':>7} {'catalog':>7} {'walks':>6} {'text MB':>8} {'wall s':>7} "
          f"{'peak RSS MB':>11}  last progress line before peak / status")
    for n, traces, text, r in rows:
        print(f"{n:5d} {traces:7d} {r['catalog'] or 0:7d} {r['walks'] or 0:6d} "
              f"{text / 1e6:8.0f} {r['wall']:7.1f} {r['peak_mb']:11.0f}  {r['phase'][:60]}"
              + ("" if r["status"] == "ok" else f" / {r['status']}"))
    base = next((r["peak_mb"] for n, _, _, r in rows if n == 1 and r["status"] == "ok"), None)
    for n, _, _, r in rows:
        if base and n != 1:
            print(f"peak RSS {n}x / 1x: {r['peak_mb'] / base:.2f}"
                  + ("" if r["status"] == "ok" else f" ({r['status']})"))
    return 0 if all(r["status"] == "ok" for *_, r in rows) else 1


if __name__ == "__main__":
    sys.exit(main())
