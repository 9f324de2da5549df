"""Deterministic seeding: one integer seed, one independent child generator per component.

Children are addressed by a key path (``child_rng(seed, "walk", 3, "imu")``) instead of by spawn
order, so adding or removing a component never shifts the random numbers of another one. Keys are
turned into :class:`numpy.random.SeedSequence` spawn keys (strings via CRC-32).
"""

from __future__ import annotations

import zlib

import numpy as np

from ..errors import SimulationError

Key = str | int


def _spawn_key(keys: tuple[Key, ...]) -> tuple[int, ...]:
    out = []
    for k in keys:
        if isinstance(k, (bool, np.bool_)):
            raise SimulationError(f"rng key must be str or int, not bool: {k!r}")
        if isinstance(k, (int, np.integer)):
            if k < 0:
                raise SimulationError(f"rng key must be non-negative: {k!r}")
            out.append(int(k))
        elif isinstance(k, str):
            out.append(zlib.crc32(k.encode("utf-8")))
        else:
            raise SimulationError(f"rng key must be str or int: {k!r}")
    return tuple(out)


def seed_sequence(seed: int, *keys: Key) -> np.random.SeedSequence:
    """The :class:`~numpy.random.SeedSequence` of the component named by ``keys``."""
    if not isinstance(seed, (int, np.integer)) or isinstance(seed, bool) or seed < 0:
        raise SimulationError(f"seed must be a non-negative integer, got {seed!r}")
    return np.random.SeedSequence(int(seed), spawn_key=_spawn_key(keys))


def child_rng(seed: int, *keys: Key) -> np.random.Generator:
    """Independent generator of one component, e.g. ``child_rng(7, "walk", 0, 2, "imu")``."""
    return np.random.default_rng(seed_sequence(seed, *keys))


def child_seed(seed: int, *keys: Key) -> int:
    """A 63-bit integer seed for a component whose generator is rebuilt elsewhere (stored in the
    ground truth, e.g. the shadowing of an access point)."""
    state = seed_sequence(seed, *keys).generate_state(1, dtype=np.uint64)
    return int(state[0] >> np.uint64(1))


def hex_id(rng: np.random.Generator, n_chars: int = 24) -> str:
    """Random lowercase hexadecimal id of ``n_chars`` characters."""
    return rng.bytes((n_chars + 1) // 2).hex()[:n_chars]
