"""Parser fuzzing (issue 8, item 1; ``../shared/RELIABILITY.md`` item 1).

A seeded, bounded fuzz run over byte mutations of real-format traces (windows of the simulated
sample in ``data/sample_site`` and factory traces written with ``write_trace``), damaged gzip
files, walk plans and sensor CSVs: strict mode raises only ``SurveyFormatError``; lenient mode
always returns, accounts for every line and keeps the documented tables; a text parses the same
in a batch as alone. Mutators and checks: ``tests/fuzzing.py``.

Every input that once made a check fail is replayed here: walk plans and CSVs kept in
``tests/data/corrupt/``, trace texts in ``tests/corrupt_texts.py`` (byte strings, not trace files),
and the damaged gzip trace generated from the simulated sample (``fuzzing.damaged_sample_gzip``).

Longer runs, one command each::

    INDOORMAP_FUZZ_EXAMPLES=20000 python -m pytest tests/test_fuzz_parsers.py
    python benchmarks/fuzz_parsers.py --minutes 10 [--save tests/data/corrupt]

``INDOORMAP_FUZZ_SEED`` changes the seed (default fixed, so the normal run is reproducible).
"""

from __future__ import annotations

import os
from pathlib import Path

import pytest
from corrupt_texts import CORRUPT_TEXTS
from fuzzing import (
    CORRUPT_DIR,
    check_corrupt_file,
    damaged_sample_gzip,
    run_fuzz,
    save_failures,
)

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


@pytest.mark.parametrize("name", sorted(CORRUPT_TEXTS))
def test_replay_corrupt_texts(name, tmp_path):
    """Trace texts that once crashed a reader (tests/corrupt_texts.py), replayed as files."""
    path = tmp_path / f"{name}.txt"
    path.write_bytes(CORRUPT_TEXTS[name])
    problems = check_corrupt_file(path, tmp_path / "work")
    assert not problems, "\n".join(problems)


def test_replay_damaged_sample_gzip(tmp_path):
    """The damaged gzip input that once leaked its messages into the next file of a batch,
    generated from the simulated sample (see fuzzing.damaged_sample_gzip)."""
    path = damaged_sample_gzip(tmp_path / "gz-messages-of-next-file.txt.gz")
    problems = check_corrupt_file(path, tmp_path / "work")
    assert not problems, "\n".join(problems)


def test_corrupt_inputs_are_small():
    assert CORRUPT, "tests/data/corrupt is empty"
    assert all(p.stat().st_size <= 16_384 for p in CORRUPT)
    assert len(CORRUPT_TEXTS) >= 13 and all(len(t) <= 16_384 for t in CORRUPT_TEXTS.values())
