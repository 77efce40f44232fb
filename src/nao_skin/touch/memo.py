"""Results kept per input object: a calibration pairs and solves the same touches dozens of times.

Keyed by the identity of the inputs (touch sets and joint arrays are large and
never modified once built), with the inputs themselves kept so that an id
reused by a new object never returns a stale result.
"""
from __future__ import annotations

from typing import Callable

_STORE: dict = {}
_LIMIT = 128


def per_objects(owners: tuple, key: tuple, compute: Callable):
    """``compute()`` once per ``key`` and identity of every object in ``owners``.

    The least recently used result goes first when the store is full: a
    calibration keeps asking for its own touch sets' results, while those of
    earlier calibrations (a benchmark runs dozens in one process) are never asked for again.
    """
    full = (*map(id, owners), *key)
    hit = _STORE.pop(full, None)
    if hit is not None and all(a is b for a, b in zip(hit[0], owners)):
        _STORE[full] = hit                      # most recently used last
        return hit[1]
    while len(_STORE) >= _LIMIT:
        del _STORE[next(iter(_STORE))]          # dicts keep insertion order: the oldest first
    value = compute()
    _STORE[full] = (owners, value)
    return value
