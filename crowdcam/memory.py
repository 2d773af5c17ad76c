"""Keep the main process's memory flat: the inspector's as tabs come and go, a run's as the
photos' maps are made in threads after the pair stage.

glibc gives each thread that allocates a malloc arena of its own (up to 8 per core), keeps what
is freed in it for reuse, and raises its mmap threshold after large blocks are freed, so that
later large blocks come from (and stay in) the arenas. Every tab has two drawing threads: with
glibc's defaults each tab left about 110 MB of resident memory behind that outlived the tab
(bench/stress.py, 3 tabs twice over: 293 -> 665 -> 843 MB), while Python and numpy held no more
than before (tracemalloc). Two arenas and a fixed 1 MB mmap threshold (large arrays always
mapped, and unmapped when freed): 303 -> 362 -> 409 MB. `crowdcam detect` and `bench` set the
same for sets of more than 9 photos (limit_arenas_for).
"""

from __future__ import annotations

import ctypes
import ctypes.util

M_MMAP_THRESHOLD = -3           # glibc's mallopt parameters (malloc.h)
M_ARENA_MAX = -8


def limit_malloc_arenas(arenas: int = 2, mmap_threshold: int = 1 << 20) -> bool:
    """Set glibc's arena count and a fixed mmap threshold for this process (arenas made from now
    on). False, doing nothing, where the C library is not glibc."""
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        mallopt = libc.mallopt
        libc.gnu_get_libc_version            # glibc only (musl has no mallopt parameters to tune)
    except (OSError, AttributeError):
        return False
    mallopt.argtypes, mallopt.restype = (ctypes.c_int, ctypes.c_int), ctypes.c_int
    return bool(mallopt(M_ARENA_MAX, arenas)) & bool(mallopt(M_MMAP_THRESHOLD, mmap_threshold))


def limit_arenas_for(n_photos: int) -> None:
    """limit_malloc_arenas for a run on a set of more than 9 photos, called before the maps' threads
    start: with glibc's defaults the memory the pair stage freed stayed resident while the map
    threads took arenas of their own (100 photos cold: 2.31 GB, limited 1.63 GB; target 2 GB).
    Not below: it makes the maps stage slower (100 photos, maps only: 80 -> 106 s), and small sets
    stay far under the target either way."""
    if n_photos > 9:
        limit_malloc_arenas()
