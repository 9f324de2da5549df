"""numba compilation with an on-disk cache when one can be written.

``numba.njit(cache=True)`` keeps compiled code beside the module (``__pycache__``) or, when that
folder is read-only, under the user's cache folder; when neither can be written (a read-only
install run by a user without a home folder, as in some containers) numba raises at import,
and every command failed with a traceback. :func:`njit_cached` then compiles without the cache:
the same code, compiled again in each process (a few seconds on the first trace read).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numba

_njit = numba.njit  # (a test replaces it)


def njit_cached(**options: Any) -> Callable[[Callable], Callable]:
    """``numba.njit(cache=True, **options)``, or without the cache when numba finds nowhere to
    write it."""
    def decorate(fn: Callable) -> Callable:
        try:
            return _njit(cache=True, **options)(fn)
        except RuntimeError as err:
            if "cannot cache function" not in str(err):
                raise
            return _njit(cache=False, **options)(fn)
    return decorate
