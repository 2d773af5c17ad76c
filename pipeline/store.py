"""Pair results by ordered pair, with bounded memory: the heavy ones live in the on-disk cache.

A pair result holds maps at working resolution and, with the depth sweep, a cost volume (some
12 MB at 640 px). A set of 100 photos with 8 supports each has 800 of them: they cannot all stay
in memory. `PairStore` keeps the most recently used `keep` results in memory and reloads the
others from the cache on access (the cache has each of them, written as it finished); the small
parts every consumer needs at once (the kind, whether the pair has a sweep, the raw confidences
for the set-level normaliser of §3.1.2) stay in memory for all. Without a cache (PairCache(None))
nothing is evicted.
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, Callable

import numpy as np


@dataclass(frozen=True)
class Light:
    """What stays in memory for every pair: kind, has a sweep, raw confidences ((P,) float32, or None)."""

    kind: str
    swept: bool
    conf_hog: np.ndarray | None
    conf_color: np.ndarray | None


def light_of(result) -> Light:
    patches = getattr(result, "patches", None)
    return Light(result.kind, getattr(result, "sweep", None) is not None,
                 None if patches is None else patches.conf_hog, None if patches is None else patches.conf_color)


class PairStore(Mapping):
    """Ordered pair -> pair result (matching.PairResult or peer.PeerPair), thread-safe.

    put(ij, result, key, decode): a finished pair and how to reload it (cache.load("pair", key,
    decode)); put_lazy: a pair in the cache, not read yet. Reading a pair that was evicted (or not
    read yet) loads it; if the cache lost it meanwhile (its own size cap, a user clearing it, a bad
    entry deleted), `recompute` computes it again, and without one KeyError names the pair.
    """

    def __init__(self, cache, keep: int = 24):
        self.cache = cache
        self.recompute: Callable[[tuple[int, int]], Any] | None = None   # a pair the cache lost or
        # found bad when read (deleted with a warning): computed again, cached, returned
        self.keep = keep if cache is not None and cache.root is not None else None
        self._mem: OrderedDict = OrderedDict()
        self._how: dict = {}
        self._light: dict = {}
        self._lock = threading.RLock()

    def put(self, ij: tuple[int, int], result: Any, key: str, decode: Callable[[bytes], Any]) -> None:
        with self._lock:
            self._how[ij] = (key, decode)
            self._light[ij] = light_of(result)
            self._mem[ij] = result
            self._mem.move_to_end(ij)
            self._trim()

    def put_lazy(self, ij: tuple[int, int], light: Light, key: str, decode: Callable[[bytes], Any]) -> None:
        """A pair known to be in the cache, by its summary alone: decoded when first read."""
        with self._lock:
            self._how[ij] = (key, decode)
            self._light[ij] = light

    def _trim(self) -> None:
        if self.keep is None:
            return
        while len(self._mem) > self.keep:
            self._mem.popitem(last=False)

    def light(self, ij: tuple[int, int]) -> Light:
        return self._light[ij]

    def __getitem__(self, ij):
        with self._lock:
            if ij in self._mem:
                self._mem.move_to_end(ij)
                return self._mem[ij]
            if ij not in self._how:
                raise KeyError(ij)
            key, decode = self._how[ij]
        result = self.cache.load("pair", key, decode)
        if result is None and self.recompute is not None:
            result = self.recompute(ij)
        if result is None:
            raise KeyError(f"pair {ij}: its result left the cache during the run; run again")
        with self._lock:
            self._mem[ij] = result
            self._trim()
        return result

    def __contains__(self, ij) -> bool:
        return ij in self._how

    def __iter__(self):
        return iter(list(self._how))

    def __len__(self) -> int:
        return len(self._how)

    def view(self) -> "StoreView":
        """The pairs finished so far, frozen: later puts do not change the view's membership."""
        with self._lock:
            return StoreView(self, frozenset(self._how))


class StoreView(Mapping):
    """A PairStore restricted to a fixed set of pairs (a consistent snapshot of a running run)."""

    def __init__(self, store: PairStore, keys: frozenset):
        self.store, self.keys_ = store, keys

    def __getitem__(self, ij):
        if ij not in self.keys_:
            raise KeyError(ij)
        return self.store[ij]

    def __contains__(self, ij) -> bool:
        return ij in self.keys_

    def __iter__(self):
        return iter(sorted(self.keys_))

    def __len__(self) -> int:
        return len(self.keys_)

    def light(self, ij):
        return self.store.light(ij)
