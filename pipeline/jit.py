"""Compiled kernels (numba), built on first use: importing the pipeline stays fast, and a worker
that never needs a kernel never compiles it (the compiled code is cached on disk, cache=True).

Kernels with `parallel=True` may be called from several threads at once (the last stage makes
photos' maps in threads; the inspector's tabs fuse in theirs). numba's OpenMP and TBB threading
layers allow that; its fallback "workqueue" layer aborts the process on a concurrent launch, so
where it is the one loaded, calls take turns.
"""

from __future__ import annotations

import threading
from typing import Callable

_TURNS = threading.Lock()
_layer_safe: bool | None = None       # None until a parallel kernel has run and the layer is known


def _threadsafe_layer() -> bool | None:
    global _layer_safe
    if _layer_safe is None:
        import numba
        try:
            _layer_safe = numba.threading_layer() != "workqueue"
        except ValueError:            # no parallel kernel has run yet
            return None
    return _layer_safe


class LazyKernel:
    """Calls the function that `make()` returns, calling `make` once, on the first call."""

    def __init__(self, make: Callable[[], Callable]):
        self._make, self._fn = make, None
        self._make_lock = threading.Lock()

    def __call__(self, *args):
        if self._fn is None:
            with self._make_lock:
                if self._fn is None:
                    self._fn = self._make()
        if _threadsafe_layer():
            return self._fn(*args)
        with _TURNS:
            return self._fn(*args)


def one_thread_per_caller() -> None:
    """Parallel kernels called from this thread use one thread (numba's setting is per calling
    thread). For a pool whose threads already fill the cores: a kernel spreading over every core
    from each of them oversubscribed the cores, and OpenMP's waiting threads spun on them (the
    maps stage of a hundred photos, 2 threads: 49.5 -> 45 s)."""
    import numba
    numba.set_num_threads(1)
