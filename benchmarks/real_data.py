"""Where the benchmarks find the real ILC traces: ``$INDOORMAP_ILC`` when set (the folder
holding ``site1/``), else ``../shared/ilc`` beside the repository. Benchmarks that need them
skip cleanly when the folder is absent."""

from __future__ import annotations

import os
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
ILC_ROOT = Path(os.environ.get("INDOORMAP_ILC") or REPO.parent / "shared" / "ilc")
ILC_SITE1 = ILC_ROOT / "site1"
