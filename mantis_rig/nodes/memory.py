"""Keeping a long bring-up's memory flat (glibc's allocator; elsewhere these do nothing).

A lab runs hundreds of trials on one bring-up. Each trial's threads, bags and integrations
allocate and free tens of MiB; with glibc's default of up to eight arenas per core, freed
memory stays spread over arenas that threads rarely come back to, and the resident memory of
the process crept up by about 2 MiB a trial for the first dozens of trials with nothing leaked
(tracemalloc saw 0.2 MiB a trial; the thread count stays bounded). Two arenas
(``limit_malloc_arenas``, called before the node threads start) and handing the freed pages
back at the end of each trial (``release_freed_memory``) keep it flat: figures in
docs/session_benchmark.md. Python holds the GIL for nearly every allocation, so two arenas
cost no contention worth measuring.
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
