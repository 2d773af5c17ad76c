"""Compiled kernels (numba), built on first use: importing the pipeline stays fast, and a worker
that never needs a kernel never compiles it (the compiled code is cached on disk, cache=True)."""

from __future__ import annotations

from typing import Callable


class LazyKernel:
    """Calls the function that `make()` returns, calling `make` once, on the first call."""

    def __init__(self, make: Callable[[], Callable]):
        self._make, self._fn = make, None

    def __call__(self, *args):
        if self._fn is None:
            self._fn = self._make()
        return self._fn(*args)
