"""Keeping a long bring-up's memory flat (glibc's allocator; elsewhere these do nothing).

A lab runs hundreds of trials on one bring-up, and each trial's threads, bags and integrations
allocate and free tens of MiB. With glibc's default of up to eight arenas per core, memory
freed by short-lived threads stays spread over arenas and the resident memory creeps up.
Measured over 20 trials on one bring-up (while scipy 1.17.1's LSODA still leaked, which was
the larger part; requirements.txt pins 1.16.3): +22 % with the defaults, +10 % with two arenas
(``limit_malloc_arenas``, called before the node threads start) and the freed pages handed
back at the end of each trial (``release_freed_memory``). Python holds the GIL for nearly
every allocation, so two arenas cost no contention worth measuring. A whole session:
docs/session_benchmark.md.
"""
from __future__ import annotations

import ctypes
import ctypes.util
import functools

M_ARENA_MAX = -8           # glibc's mallopt parameter
ARENAS = 2


@functools.cache
def _libc():
    name = ctypes.util.find_library('c')
    if name is None:
        return None
    try:
        libc = ctypes.CDLL(name)
        return libc if hasattr(libc, 'mallopt') and hasattr(libc, 'malloc_trim') else None
    except OSError:
        return None


def limit_malloc_arenas(arenas: int = ARENAS) -> bool:
    """At most ``arenas`` malloc arenas from now on; True if glibc took it."""
    libc = _libc()
    return bool(libc.mallopt(M_ARENA_MAX, arenas)) if libc is not None else False


def release_freed_memory() -> bool:
    """Return the process's freed heap pages to the system; True if glibc released some."""
    libc = _libc()
    return bool(libc.malloc_trim(0)) if libc is not None else False
