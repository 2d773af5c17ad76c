"""glibc's malloc, tuned where its defaults cost memory or time.

The inspector (limit_malloc_arenas): glibc gives each thread that allocates a malloc arena of
its own (up to 8 per core), keeps what is freed in it for reuse, and raises its mmap threshold
after large blocks are freed, so that later large blocks come from (and stay in) the arenas. Every
tab has two drawing threads: with glibc's defaults each tab left about 110 MB of resident memory
behind that outlived the tab (bench/stress.py, 3 tabs twice over: 293 -> 665 -> 843 MB), while
Python and numpy held no more than before (tracemalloc). Two arenas and a fixed 1 MB mmap
threshold (large arrays always mapped, and unmapped when freed): 303 -> 362 -> 409 MB.

A run's pool workers (keep_freed_memory) are the opposite case: one thread each, the same large
arrays made and freed pair after pair. With glibc's defaults the arrays above its dynamic mmap
threshold (at most 32 MB) were mapped and unmapped every time, and every page of them faulted in
anew: the hundred photos cold spent 50 s of system time. A fixed 64 MB threshold keeps them in the
heap for reuse.

`crowdcam detect` and `bench` used to limit the arenas of their main process too, for the photos'
maps made in threads after the pair stage (a hundred photos cold peaked at 2.31 GB, limited 1.63
GB). Since the pairs stay on disk until a map reads them and the ground plane's SVD is thin, the
peak without the limit is 1.5 GB, and the limit cost the maps stage half its time (the mapping of
every large array, 33 s of system time on a hundred photos): no longer set there.
"""

from __future__ import annotations

import ctypes
import ctypes.util

M_TRIM_THRESHOLD = -1           # glibc's mallopt parameters (malloc.h)
M_MMAP_THRESHOLD = -3
M_ARENA_MAX = -8


def _mallopt():
    """glibc's mallopt, or None where the C library is not glibc (musl has no such parameters)."""
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        mallopt = libc.mallopt
        libc.gnu_get_libc_version
    except (OSError, AttributeError):
        return None
    mallopt.argtypes, mallopt.restype = (ctypes.c_int, ctypes.c_int), ctypes.c_int
    return mallopt


def limit_malloc_arenas(arenas: int = 2, mmap_threshold: int = 1 << 20) -> bool:
    """Set glibc's arena count and a fixed mmap threshold for this process (arenas made from now
    on). False, doing nothing, where the C library is not glibc."""
    mallopt = _mallopt()
    return mallopt is not None and bool(mallopt(M_ARENA_MAX, arenas)) & bool(mallopt(M_MMAP_THRESHOLD, mmap_threshold))


def keep_freed_memory(mmap_threshold: int = 64 << 20, trim_threshold: int = 128 << 20) -> bool:
    """For a process that makes and frees the same large arrays over and over (a pool worker):
    blocks under `mmap_threshold` come from the heap and freed memory up to `trim_threshold` stays
    there for the next task, instead of being mapped, unmapped and faulted in anew each time.
    False, doing nothing, where the C library is not glibc."""
    mallopt = _mallopt()
    return mallopt is not None and bool(mallopt(M_MMAP_THRESHOLD, mmap_threshold)) & bool(
        mallopt(M_TRIM_THRESHOLD, trim_threshold))
