"""The README's Python API example runs as written on the simulated sample site."""

from __future__ import annotations

import re
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
SITE = REPO / "data" / "sample_site"


def test_readme_python_example_runs(tmp_path, monkeypatch):
    text = (REPO / "README.md").read_text()
    blocks = re.findall(r"```python\n(.*?)```", text, flags=re.DOTALL)
    assert len(blocks) == 1, "the README has one Python example"
    walk = min((SITE / "F1" / "path_data_files").glob("*.txt.gz"))
    code = blocks[0].replace('"site1/F1"', repr(str(SITE / "F1"))) \
                    .replace('"walk.txt.gz"', repr(str(walk)))
    monkeypatch.chdir(tmp_path)  # the example writes under out/
    namespace: dict = {}
    exec(compile(code, "README.md", "exec"), namespace)  # noqa: S102 (the README's own code)
    track, bundle = namespace["track"], namespace["bundle"]
    assert len(track.x_m) == len(namespace["steps"]) > 10
    row, col, inside = bundle.grid.cell_of(track.x_m, track.y_m)
    assert inside.all() and bundle.mask[row, col].mean() > 0.9  # the walk stays on the floor
    assert len(namespace["mag"]) > 1000  # the store query returns the magnetometer rows
