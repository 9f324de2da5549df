"""Parser fuzzing (issue 8, item 1; ``../shared/RELIABILITY.md`` item 1).

A seeded, bounded fuzz run over byte mutations of real-format traces (windows of the simulated
sample in ``data/sample_site`` and factory traces written with ``write_trace``), damaged gzip
files, walk plans and sensor CSVs: strict mode raises only ``SurveyFormatError``; lenient mode
always returns, accounts for every line and keeps the documented tables; a text parses the same
in a batch as alone. Mutators and checks: ``tests/fuzzing.py``.

Every input that once made a check fail is kept in ``tests/data/corrupt/`` and replayed here.

Longer runs, one command each::

    INDOORMAP_FUZZ_EXAMPLES=20000 python -m pytest tests/test_fuzz_parsers.py
    python benchmarks/fuzz_parsers.py --minutes 10 [--save tests/data/corrupt]

``INDOORMAP_FUZZ_SEED`` changes the seed (default fixed, so the normal run is reproducible).
"""

from __future__ import annotations

import os
from pathlib import Path

import pytest
from fuzzing import CORRUPT_DIR, check_corrupt_file, run_fuzz, save_failures

#: Mutated inputs in the normal run (split: 50% trace texts, 7% gzip files, 43% walk-line).
EXAMPLES = int(os.environ.get("INDOORMAP_FUZZ_EXAMPLES", "330"))
SEED = int(os.environ.get("INDOORMAP_FUZZ_SEED", "8"))
SAVE = os.environ.get("INDOORMAP_FUZZ_SAVE")  # a folder to keep minimized failing inputs in

SPLIT = {"texts": 0.50, "gz_cases": 0.07, "walk_cases": 0.43}


def _report(stats, tmp_path: Path) -> str:
    if SAVE:
        save_failures(stats, Path(SAVE), tmp_path / "save")
    lines = [(f"{len(stats.failures)} of {stats.total} mutated inputs failed "
              f"(seed {SEED}; set INDOORMAP_FUZZ_SAVE=tests/data/corrupt to keep them):")]
    for (kind, sig), failures in sorted(stats.by_signature().items()):
        f = failures[0]
        lines.append(f"  {len(failures)} x {kind} {sig}: {f.problems[0][:300]}\n"
                     f"      input ({len(f.data)} bytes): {f.data[:300]!r}")
    return "\n".join(lines)


@pytest.mark.parametrize("part", list(SPLIT))
def test_fuzz_parsers(part, tmp_path):
    count = max(1, round(EXAMPLES * SPLIT[part]))
    stats = run_fuzz(SEED + list(SPLIT).index(part), tmp_path, **{part: count},
                     full_traces=1 if part == "gz_cases" else 0, sample_files=2,
                     ingest_every=10)
    assert stats.total >= count
    assert not stats.failures, _report(stats, tmp_path)


_REPLAYED = (".txt", ".txt.gz", ".geojson", ".csv")
CORRUPT = sorted(p for p in CORRUPT_DIR.glob("*") if p.name.endswith(_REPLAYED))


@pytest.mark.parametrize("path", CORRUPT, ids=[p.name for p in CORRUPT])
def test_replay_corrupt_inputs(path, tmp_path):
    """Inputs that once crashed a parser or broke an invariant (see tests/data/corrupt)."""
    problems = check_corrupt_file(path, tmp_path)
    assert not problems, "\n".join(problems)


def test_corrupt_inputs_are_small():
    assert CORRUPT, "tests/data/corrupt is empty"
    assert all(p.stat().st_size <= 16_384 for p in CORRUPT)
