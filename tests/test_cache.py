"""The cache heals: bad entries are reported, deleted and recomputed; a size cap evicts the least
recently used entries; `crowdcam cache info|clear`."""

import os
import subprocess
import sys
import time

import numpy as np
import pytest

from conftest import ROOT, SAMPLE_SETS
from pipeline.cache import PairCache, pack, unpack


def test_entries_carry_a_checked_header(tmp_path):
    c = PairCache(tmp_path)
    c.put("pair", "ab" * 12, b"payload")
    raw = c.path("pair", "ab" * 12).read_bytes()
    assert raw != b"payload" and unpack(raw) == b"payload"
    assert c.get("pair", "ab" * 12) == b"payload"


@pytest.mark.parametrize("damage", ["empty", "truncated", "flipped", "foreign"])
def test_a_bad_entry_is_reported_deleted_and_missed(tmp_path, damage):
    warnings = []
    c = PairCache(tmp_path, warn=warnings.append)
    key = "cd" * 12
    c.put("geometry", key, b"x" * 1000)
    p = c.path("geometry", key)
    raw = p.read_bytes()
    p.write_bytes({"empty": b"", "truncated": raw[:-10], "flipped": raw[:-1] + bytes([raw[-1] ^ 1]),
                   "foreign": b"PK\x03\x04" + raw[4:]}[damage])
    assert c.get("geometry", key) is None
    assert not p.exists() and c.healed == 1
    assert len(warnings) == 1 and str(p) in warnings[0] and "recomputed" in warnings[0]


def test_an_entry_that_does_not_decode_is_healed_too(tmp_path):
    warnings = []
    c = PairCache(tmp_path, warn=warnings.append)
    c.put("pair", "ef" * 12, b"not an npz")
    assert c.load("pair", "ef" * 12, lambda d: __import__("numpy").load(__import__("io").BytesIO(d))) is None
    assert not c.path("pair", "ef" * 12).exists() and warnings


def test_size_cap_evicts_least_recently_used(tmp_path):
    """Entries of earlier runs go, least recently used first; a run never evicts what it wrote
    or read itself (it may still need it)."""
    earlier = PairCache(tmp_path, max_bytes=None)
    keys = [f"{k:02d}" * 12 for k in range(6)]
    for k in keys[:4]:
        earlier.put("pair", k, os.urandom(2000))
    old = time.time() - 100
    for n, k in enumerate(keys[:4]):                  # ages: keys[0] oldest
        os.utime(earlier.path("pair", k), (old + n, old + n))
    c = PairCache(tmp_path, max_bytes=10_000)         # this run
    c.get("pair", keys[0])                            # used now by this run
    c.put("pair", keys[4], os.urandom(2000))
    c.put("pair", keys[5], os.urandom(2000))          # over 10 kB: evict down to 9 kB
    left = {p.stem for p, _, _ in c.entries()}
    assert {keys[0], keys[4], keys[5]} <= left        # this run's own
    assert keys[1] not in left                        # the oldest of the others
    assert c.size() <= 10_000


def test_an_entry_written_elsewhere_is_adopted_as_this_runs(tmp_path):
    """A pool worker writes its pair's entry itself (PairCache.write); the run's cache adopts it:
    counted against the cap and never evicted by this run, as if it had put it."""
    earlier = PairCache(tmp_path, max_bytes=None)
    earlier.put("pair", "aa" * 12, os.urandom(4000))
    old = time.time() - 100
    os.utime(earlier.path("pair", "aa" * 12), (old, old))
    c = PairCache(tmp_path, max_bytes=6_000)
    worker = PairCache(tmp_path, max_bytes=None)                  # another process's view of the folder
    n = worker.write("pair", "bb" * 12, os.urandom(4000))
    assert n > 4000 and unpack(c.path("pair", "bb" * 12).read_bytes())
    c.adopt("pair", "bb" * 12, n)                                # over 6 kB: the earlier run's entry goes
    left = {p.stem for p, _, _ in c.entries()}
    assert left == {"bb" * 12}
    assert PairCache(None).write("pair", "cc" * 12, b"x") == 0    # no cache: nothing written
    (tmp_path / "pair" / "dd").write_text("a file where the folder should be")
    assert worker.write("pair", "dd" * 12, b"x") == 0               # cannot be written: 0, no exception


def run_cli(*args):
    return subprocess.run([sys.executable, "-m", "crowdcam", *map(str, args)], capture_output=True, text=True,
                          cwd=ROOT, timeout=600)


def test_detect_heals_a_truncated_cache_entry(tmp_path):
    """An empty geometry entry (a crash or a full disk) used to end every later run in a traceback."""
    cache = tmp_path / "cache"
    args = ["detect", SAMPLE_SETS / "tabletop_ball", "--out", tmp_path / "out", "--max-side", "200", "--preset",
            "paper", "--quiet", "--cache-dir", cache]
    assert run_cli(*args).returncode == 0
    geo = sorted((cache / "geometry").rglob("*.npz"))
    assert geo
    geo[0].write_bytes(b"")
    r = run_cli(*args)
    assert r.returncode == 0, r.stderr
    assert "Traceback" not in r.stderr and "bad cache entry" in r.stderr and str(geo[0]) in r.stderr
    assert geo[0].stat().st_size > 0                       # recomputed and written again
    r = run_cli("cache", "info", "--cache-dir", cache)
    assert r.returncode == 0 and "geometry" in r.stdout and "pair" in r.stdout
    r = run_cli("cache", "clear", "--cache-dir", cache)
    assert r.returncode == 0 and not list(cache.rglob("*.npz"))


def test_a_rerun_reads_no_pair_and_a_bad_pair_read_later_is_recomputed(tmp_path):
    """A re-run with nothing changed takes every photo's map from the cache without decoding a
    pair; a pair entry that went bad meanwhile is found when a viewer reads it, and is computed
    again (with a warning), equal to what it was."""
    from pipeline.loading import load_set
    from pipeline.params import get_preset
    from pipeline.run import detect_set
    params = get_preset("paper").replace(max_side=160)
    photos = load_set(SAMPLE_SETS / "tabletop_ball", params.max_side)
    first = detect_set(photos, params, PairCache(tmp_path), workers=1)
    ij = next(iter(first.pair_results))
    before = first.pair_results[ij].hog_map.copy()
    p = next(iter((tmp_path / "pair").rglob("*.npz")))
    raw = bytearray(p.read_bytes())
    raw[len(raw) // 2] ^= 0xFF                       # same length: only its checksum tells
    p.write_bytes(bytes(raw))
    warnings = []
    cache = PairCache(tmp_path, warn=warnings.append)
    again = detect_set(photos, params, cache, workers=1)
    assert cache.misses == 0 and not warnings         # maps from the cache, no pair decoded
    assert all((a is None and b is None) or np.array_equal(a, b) for a, b in zip(first.dynamic, again.dynamic))
    for k in again.pair_results:                      # a viewer reads the pairs: the bad one heals
        r = again.pair_results[k]
        if k == ij:
            np.testing.assert_array_equal(r.hog_map, before)
    assert len(warnings) == 1 and "bad cache entry" in warnings[0]
    unpack(p.read_bytes())                            # written again, whole


def test_a_volume_stored_as_differences_comes_back_exactly():
    """uint8 fields stored as differences along their last axis (mod 256) decode to the same bytes."""
    from pipeline.cache import from_bytes, to_bytes
    from pipeline.sweep import SweepPair
    rng = np.random.default_rng(0)
    cost = rng.integers(0, 256, (5, 6, 40), dtype=np.uint8)
    cost[:, :, 10:20] = 255                                   # unseen planes, and a wrap around 0/255
    pair = SweepPair(0, 1, cost, np.zeros((40, 4)), 0.5)
    back = from_bytes(SweepPair, to_bytes(pair, delta=("cost",)))
    assert back.cost.dtype == np.uint8 and np.array_equal(back.cost, cost)
    assert from_bytes(SweepPair, to_bytes(pair)).cost.tobytes() == cost.tobytes()     # without, as before
    # what is stored is np.diff's differences (the compiled pass writes the format entries had before)
    from pipeline.cache import _unpack_arrays
    stored = _unpack_arrays(to_bytes(pair, delta=("cost",)))[1]["cost"]
    assert np.array_equal(stored, np.diff(cost, axis=-1, prepend=np.zeros((5, 6, 1), np.uint8)))


def test_entries_are_zstd_framed_and_older_entries_still_read():
    """The payload is one zstd frame around the arrays' own layout; entries written before (an npz in
    a zstd frame, and before that a plain deflated npz, as np.savez_compressed makes) decode to the
    same result. Arrays read back are writable, as np.load's were."""
    import io
    import json

    import zstandard

    from pipeline.cache import from_bytes, to_bytes
    from pipeline.sweep import SweepPair
    cost = np.arange(2 * 3 * 7, dtype=np.uint8).reshape(2, 3, 7)
    pair = SweepPair(2, 5, cost, np.ones((7, 4)), 0.25)
    data = to_bytes(pair)
    assert data[:4] == b"\x28\xb5\x2f\xfd"
    meta = {"ref": 2, "sup": 5, "seconds": 0.25, "kind": "plane"}
    fields = dict(cost=cost, planes=np.ones((7, 4)), __meta__=np.frombuffer(json.dumps(meta).encode(), np.uint8))
    deflated, plain = io.BytesIO(), io.BytesIO()
    np.savez_compressed(deflated, **fields)
    np.savez(plain, **fields)
    assert deflated.getvalue()[:2] == b"PK"
    for blob in (data, deflated.getvalue(), zstandard.ZstdCompressor(level=1).compress(plain.getvalue())):
        back = from_bytes(SweepPair, blob)
        assert (back.ref, back.sup, back.seconds) == (2, 5, 0.25)
        assert np.array_equal(back.cost, cost) and np.array_equal(back.planes, np.ones((7, 4)))
        assert back.cost.flags.writeable and back.planes.flags.writeable
        # each its own memory: a view would keep the entry's whole buffer alive as long as the
        # store keeps a pair's small arrays (9 GB on a hundred photos)
        for a in (back.cost, back.planes):
            while isinstance(a.base, np.ndarray):
                a = a.base
            assert a.base is None or memoryview(a.base).nbytes == a.nbytes


def test_every_kind_of_array_survives_the_layout():
    """Empty, 0-d, non-contiguous, big-endian, bool and float16 arrays, and nested dataclasses."""
    from dataclasses import dataclass

    from pipeline.cache import from_bytes, to_bytes

    @dataclass(frozen=True)
    class Inner:
        a: np.ndarray
        note: str

    @dataclass(frozen=True)
    class Outer:
        empty: np.ndarray
        scalar: np.ndarray
        strided: np.ndarray
        big: np.ndarray
        flags: np.ndarray
        half: np.ndarray
        inner: Inner
        n: int

    base = np.arange(60, dtype=np.float64).reshape(6, 10)
    obj = Outer(np.zeros((0, 3), np.int32), np.array(3.5), base[::2, 1::3], np.arange(5, dtype=">i4"),
                np.array([True, False, True]), np.linspace(0, 1, 7).astype(np.float16),
                Inner(np.ones((2, 2, 2), np.uint8), "x"), 7)
    globals()["Inner"], globals()["Outer"] = Inner, Outer      # _unflatten resolves nested hints by module
    back = from_bytes(Outer, to_bytes(obj))
    for name in ("empty", "scalar", "strided", "big", "flags", "half"):
        a, b = getattr(obj, name), getattr(back, name)
        assert a.dtype == b.dtype and a.shape == b.shape and np.array_equal(a, b), name
    assert np.array_equal(back.inner.a, obj.inner.a) and back.inner.note == "x" and back.n == 7
