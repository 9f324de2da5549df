"""numba compilation falls back to no cache when the cache cannot be written."""

import numba
import numpy as np
import pytest

from survey import compiled


def test_no_cache_folder_compiles_without_cache(monkeypatch):
    """With no writable cache folder (a read-only install, no home folder) numba raised at
    import and every command failed; the function is now compiled without the cache."""
    real = numba.njit
    calls = []

    def njit(**options):
        calls.append(options["cache"])
        if options["cache"]:
            raise RuntimeError("cannot cache function 'f': no locator available for file 'x'")
        return real(**options)

    monkeypatch.setattr(compiled, "_njit", njit)

    @compiled.njit_cached(nogil=True)
    def total(a):
        s = 0.0
        for v in a:
            s += v
        return s

    assert total(np.arange(4.0)) == 6.0 and calls == [True, False]


def test_other_errors_are_not_hidden(monkeypatch):
    def njit(**options):
        raise RuntimeError("something else")

    monkeypatch.setattr(compiled, "_njit", njit)
    with pytest.raises(RuntimeError, match="something else"):
        compiled.njit_cached()(lambda a: a)
