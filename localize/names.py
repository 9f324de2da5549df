"""Names that become folder and file names: a floor's key in the survey store, the bundle
registry and a build's output (``Level 1`` is stored as ``Level_1``). Here, not in
:mod:`survey.store`, because the localizer's runtime finds a walk's floor by it and imports
no pandas."""

from __future__ import annotations

import hashlib
import re


def safe_component(value: str | None, fallback: str) -> str:
    """``value`` usable as a folder or file name (``[A-Za-z0-9_.-]``, not starting with a
    dot, at most 80 characters); ``fallback`` when it is empty."""
    text = re.sub(r"[^A-Za-z0-9_.-]", "_", (value or "").strip()) or fallback
    return (("_" + text[1:]) if text.startswith(".") else text)[:80]


def floor_key(floor: str | None) -> str:
    """The store's ``floor`` key of a walk of this floor name or id (None or empty:
    ``unknown_floor``)."""
    return safe_component(floor, "unknown_floor")


def file_stem(trace_id: str) -> str:
    """A file name for a walk's output (``localize -o``): its trace id when that is a safe
    name (``[A-Za-z0-9_.-]``, at most 80 characters, not starting with a dot), else the id
    made one plus 8 hex digits of its sha256, so that ``../x`` or ``a/b`` stays in the output
    folder and two ids made alike (``a/b``, ``a_b``) do not share a file."""
    safe = safe_component(trace_id, "trace")
    if safe == trace_id:
        return safe
    return f"{safe[:71]}-{hashlib.sha256(trace_id.encode()).hexdigest()[:8]}"
