"""On-disk cache of per-pair results, keyed by image content and parameters.

Entries are arrays in one zstd frame (an npz before) behind a small header (magic, format
version, payload length, SHA-256), written atomically (temporary file + rename), so an
interrupted run never leaves a half-written entry in place. On read the header is checked: a truncated, corrupt or foreign entry (a crash, a
full disk, another version) is reported as a warning, deleted and recomputed, never a traceback.
Reads refresh an entry's time, and a size cap evicts the least recently used entries. Maps are
stored as float16 and every result, fresh or cached, goes through the same quantisation, so a
cached run gives exactly the maps of a cold run.
"""

from __future__ import annotations

import dataclasses
import hashlib
import io
import json
import os
import struct
import tempfile
import threading
from pathlib import Path
from typing import Any, Callable

import numpy as np
import zstandard

from .jit import LazyKernel
from .params import digest

CODE_VERSION = "14"      # bump when a change alters per-pair results


def default_cache_dir() -> Path:
    env = os.environ.get("CROWDCAM_CACHE")
    if env:
        return Path(env)
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "crowdcam"


def _flatten(obj: Any, prefix: str, arrays: dict, meta: dict) -> None:
    for f in dataclasses.fields(obj):
        v = getattr(obj, f.name)
        key = f"{prefix}{f.name}"
        if dataclasses.is_dataclass(v):
            meta[key] = {"__dataclass__": True}
            _flatten(v, key + ".", arrays, meta)
        elif isinstance(v, np.ndarray):
            arrays[key] = v
        else:
            meta[key] = v


def _unflatten(cls: type, prefix: str, arrays: dict, meta: dict) -> Any:
    kwargs = {}
    hints = {f.name: f.type for f in dataclasses.fields(cls)}
    for f in dataclasses.fields(cls):
        key = f"{prefix}{f.name}"
        if key in arrays:
            kwargs[f.name] = arrays[key]
        elif key not in meta:
            continue                      # a field with a default, absent from older entries
        elif isinstance(meta.get(key), dict) and meta[key].get("__dataclass__"):
            kwargs[f.name] = _unflatten(_resolve(cls, hints[f.name]), key + ".", arrays, meta)
        else:
            v = meta[key]
            kwargs[f.name] = tuple(v) if isinstance(v, list) else v
    return cls(**kwargs)


def _resolve(owner: type, hint: Any) -> type:
    if isinstance(hint, str):
        import sys
        return getattr(sys.modules[owner.__module__], hint.split("|")[0].strip())
    return hint


def to_bytes(obj: Any, float16: tuple[str, ...] = (), delta: tuple[str, ...] = ()) -> bytes:
    """A dataclass (nested ones too) as an npz in a zstd frame. float16: fields stored as float16;
    delta: uint8 fields stored as differences along their last axis (mod 256), which pack better
    (a cost volume, smooth along its planes: 46 % -> 40 % of its size)."""
    arrays: dict[str, np.ndarray] = {}
    meta: dict[str, Any] = {}
    _flatten(obj, "", arrays, meta)
    for k in float16:
        if k in arrays:               # a field may be None (a pair without that map)
            arrays[k] = arrays[k].astype(np.float16)
    deltas = [k for k in delta if k in arrays and arrays[k].dtype == np.uint8 and arrays[k].ndim]
    for k in deltas:
        arrays[k] = _delta(arrays[k], undo=False)            # wraps mod 256
    if deltas:
        meta["__delta__"] = deltas
    size, chunks = _packed_chunks(meta, arrays)
    # streamed into the frame: the ten-odd MB of a swept pair are never copied into one buffer first
    # (7 ms a pair); the size pledged up front goes into the frame's header, as a one-shot frame's
    z = zstandard.ZstdCompressor(level=ZSTD_LEVEL).compressobj(size=size)
    return b"".join([*(z.compress(c) for c in chunks), z.flush()])


# zstd's fast level -2: a swept pair compresses in 12 ms instead of level 1's 19 and reads back in
# 6 ms instead of 14 (the photos' maps read every pair of the run: a hundred photos' maps stage,
# 748 pairs, about 6 s less), for entries 22 % larger (4.8 MB instead of 3.9 for such a pair)
ZSTD_LEVEL = -2
_ZSTD_MAGIC = b"\x28\xb5\x2f\xfd"          # a zstd frame's first bytes (an npz begins "PK")
_RAW_MAGIC = b"CCARRAY1"
_ALIGN = 64


def _packed_chunks(meta: dict, arrays: dict[str, np.ndarray]) -> tuple[int, list]:
    """meta and arrays as one buffer, given as (its length, its pieces in order): _RAW_MAGIC, a
    little-endian uint32 length, a JSON header (meta, and per array its name, dtype, shape and
    offset), then the arrays' bytes, each aligned (zero padding between them).

    Before this, an uncompressed npz went into the zstd frame (deflate, level 1, had taken 0.3 s of
    CPU per swept pair; zstd level 1 takes 0.06 s, reads back 5x faster and is a little smaller). A
    pair holds about forty arrays, and the npz's per-array zip entry, CRC and header parsed with
    ast.literal_eval cost about 40 ms to read back (the photos' maps read every pair of the run)
    and 10 ms to write; this layout is read with one JSON parse and a view per array.
    """
    table, blocks, offset = [], [], 0
    for name, a in arrays.items():
        shape = list(a.shape)
        a = np.ascontiguousarray(a)            # (which makes a 0-d array 1-d: the shape is taken before)
        offset += -offset % _ALIGN
        table.append([name, a.dtype.str, shape, offset])
        blocks.append((offset, a))
        offset += a.nbytes
    head = json.dumps({"meta": meta, "arrays": table}).encode()
    start = len(_RAW_MAGIC) + 4 + len(head)
    start += -start % _ALIGN
    chunks = [_RAW_MAGIC + struct.pack("<I", len(head)) + head]
    at = len(chunks[0])
    for off, a in blocks:
        if start + off > at:
            chunks.append(bytes(start + off - at))
        chunks.append(memoryview(a.reshape(-1).view(np.uint8)))
        at = start + off + a.nbytes
    if start + offset > at:                    # no arrays: the header's padding still counts
        chunks.append(bytes(start + offset - at))
    return start + offset, chunks


def _unpack_arrays(data, replaced: Callable[[str, dict, np.dtype], bool] = lambda *_: False
                   ) -> tuple[dict, dict[str, np.ndarray]]:
    """(meta, arrays) of an entry's payload: this format, or an npz (zstd-framed or, older, plain
    deflated) as written before, which still reads. The arrays are writable and own their memory,
    but those for which replaced(name, meta, dtype) is true: views of the payload, which the caller
    replaces by new arrays at once (decoded, converted), so a copy would be thrown away."""
    if bytes(data[:4]) == _ZSTD_MAGIC:
        data = zstandard.ZstdDecompressor().decompress(data)
    if bytes(data[:len(_RAW_MAGIC)]) != _RAW_MAGIC:
        with np.load(io.BytesIO(data), allow_pickle=False) as z:
            meta = json.loads(bytes(z["__meta__"]).decode())
            return meta, {k: z[k] for k in z.files if k != "__meta__"}
    (n,) = struct.unpack_from("<I", data, len(_RAW_MAGIC))
    head = json.loads(bytes(data[len(_RAW_MAGIC) + 4:len(_RAW_MAGIC) + 4 + n]))
    start = len(_RAW_MAGIC) + 4 + n
    start += -start % _ALIGN
    arrays = {}
    for name, dtype, shape, off in head["arrays"]:
        dt = np.dtype(dtype)
        count = int(np.prod(shape, dtype=np.int64))
        # a copy of each, not a view: a view keeps the whole buffer alive, and the store keeps a
        # pair's small arrays long after its volume is gone (9 GB on a hundred photos with views)
        view = np.frombuffer(data, dt, count, start + off).reshape(shape)
        arrays[name] = view if replaced(name, head["meta"], dt) else view.copy()
    return head["meta"], arrays


def from_bytes(cls: type, data: bytes, float32: tuple[str, ...] = ()) -> Any:
    # the volume's differences and the float16 maps are decoded into new arrays: read without a copy
    # (a swept pair's 5 MB volume: 2 ms of the 14 its decoding took in the photos' maps)
    meta, arrays = _unpack_arrays(data, lambda name, meta, dt: name in meta.get("__delta__", ())
                                  or (name in float32 and dt != np.float32))
    for k in meta.pop("__delta__", []):
        arrays[k] = _delta(arrays[k], undo=True)
    for k in float32:
        if k in arrays:
            arrays[k] = arrays[k].astype(np.float32)
    return _unflatten(cls, "", arrays, meta)


def _delta_numba():
    """Differences along the last axis of a uint8 array (mod 256; the first element kept), or with
    undo=True their running sums, which give the array back: np.diff and np.cumsum(dtype=uint8) in one
    compiled pass (numba), 5-10x faster on a cost volume (a hundred planes per pixel: numpy's
    loops restart at every pixel). Decoding ran in the main process for every pair of a map."""
    import numba

    @numba.njit(cache=True, nogil=True)
    def kernel(a, undo):
        flat = a.reshape(-1, a.shape[-1])
        out = np.empty_like(flat)
        for i in range(flat.shape[0]):
            prev = np.uint8(0)
            for k in range(flat.shape[1]):
                v = flat[i, k]
                if undo:
                    prev = np.uint8(prev + v)
                    out[i, k] = prev
                else:
                    out[i, k] = np.uint8(v - prev)
                    prev = v
        return out.reshape(a.shape)
    return kernel


_delta_kernel = LazyKernel(_delta_numba)


def _delta(a: np.ndarray, undo: bool) -> np.ndarray:
    """_delta_numba's kernel for a uint8 array of any shape (an empty one is returned as it is)."""
    return a.copy() if a.size == 0 else _delta_kernel(np.ascontiguousarray(a), undo)


def atomic_write_bytes(path: Path, data: bytes) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=".tmp-", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
        os.replace(tmp, path)
    except BaseException:
        try:
            os.unlink(tmp)
        except OSError:
            pass
        raise


MAGIC = b"CCCACHE1"
FORMAT = 1
_HEADER = struct.Struct("<8sIQ32s")            # magic, format, payload length, sha256 of the payload


def pack(payload: bytes) -> bytes:
    """Header + payload, as stored on disk."""
    return _HEADER.pack(MAGIC, FORMAT, len(payload), hashlib.sha256(payload).digest()) + payload


def unpack(data: bytes) -> bytes:
    """The payload of a stored entry; ValueError naming what is wrong with it."""
    if len(data) < _HEADER.size:
        raise ValueError(f"truncated ({len(data)} bytes)")
    magic, fmt, length, digest = _HEADER.unpack_from(data)
    if magic != MAGIC:
        raise ValueError("not a crowdcam cache entry")
    if fmt != FORMAT:
        raise ValueError(f"cache format {fmt}, expected {FORMAT}")
    payload = data[_HEADER.size:]
    if len(payload) != length:
        raise ValueError(f"truncated ({len(payload)} of {length} bytes)")
    if hashlib.sha256(payload).digest() != digest:
        raise ValueError("checksum mismatch")
    return payload


class PairCache:
    """Get/put serialised results by key. `root=None` disables caching.

    max_bytes: size cap; after writes beyond it the least recently used entries are evicted
    (down to 90 %). warn: called with a one-line message for every bad entry found.
    """

    def __init__(self, root: Path | None, max_bytes: int | None = 5 * 2**30, warn: Callable[[str], None] | None = None):
        self.root = Path(root) if root is not None else None
        self.max_bytes = max_bytes
        self.warn = warn
        self.hits = 0                       # counted under _count_lock: the photos' maps read in threads
        self.misses = 0
        self.healed = 0
        self._size: int | None = None       # bytes under root, scanned on the first write
        self._lock = threading.Lock()
        self._count_lock = threading.Lock()
        self._mine: set[Path] = set()       # written or read by this run: never evicted by it

    def path(self, kind: str, key: str) -> Path | None:
        return None if self.root is None else self.root / kind / key[:2] / f"{key}.npz"

    def _count(self, hits: int = 0, misses: int = 0, healed: int = 0) -> None:
        with self._count_lock:
            self.hits += hits
            self.misses += misses
            self.healed += healed

    def _bad(self, p: Path, why: str) -> None:
        self._count(healed=1)
        if self.warn is not None:
            self.warn(f"{p}: bad cache entry ({why}); deleted, it will be recomputed")
        try:
            p.unlink()
        except OSError:
            pass

    def get(self, kind: str, key: str) -> bytes | None:
        """The payload of an entry, or None (missing, unreadable, or bad: then deleted)."""
        p = self.path(kind, key)
        if p is None or not p.exists():
            self._count(misses=1)
            return None
        try:
            data = p.read_bytes()
        except OSError:
            self._count(misses=1)
            return None
        try:
            payload = unpack(data)
        except ValueError as e:
            self._bad(p, str(e))
            self._count(misses=1)
            return None
        try:
            os.utime(p)                      # least recently *used* goes first
        except OSError:
            pass
        self._mine.add(p)
        self._count(hits=1)
        return payload

    def has(self, kind: str, key: str) -> bool:
        """The entry is there and whole (its header and length; the checksum is checked when it is
        read), without reading it: refreshes its time and keeps it from this run's evictions."""
        p = self.path(kind, key)
        if p is None:
            return False
        try:
            size = p.stat().st_size
            with open(p, "rb") as f:
                head = f.read(_HEADER.size)
        except OSError:
            return False
        if len(head) < _HEADER.size:
            return False
        magic, fmt, length, _ = _HEADER.unpack(head)
        if magic != MAGIC or fmt != FORMAT or size != _HEADER.size + length:
            return False
        try:
            os.utime(p)
        except OSError:
            pass
        self._mine.add(p)
        return True

    def load(self, kind: str, key: str, decode: Callable[[bytes], Any]) -> Any | None:
        """get() and decode; an entry that passes its checksum but does not decode (written by
        other code) is treated like a bad one."""
        data = self.get(kind, key)
        if data is None:
            return None
        try:
            return decode(data)
        except Exception as e:
            self._count(hits=-1, misses=1)
            self._bad(self.path(kind, key), f"cannot be decoded: {type(e).__name__}")
            return None

    def put(self, kind: str, key: str, data: bytes) -> None:
        self.adopt(kind, key, self.write(kind, key, data))

    def write(self, kind: str, key: str, data: bytes) -> int:
        """The entry written in place (atomically), without this cache's bookkeeping: the bytes on
        disk, 0 if it could not be written (a cache that cannot be written only costs time). A pool
        worker writes its pair's entry itself and the run's cache adopts it: the ~5 MB of a swept
        pair then never crosses the pipe to the main process (~10 ms of CPU a pair, both sides)."""
        p = self.path(kind, key)
        if p is None:
            return 0
        blob = pack(data)
        try:
            atomic_write_bytes(p, blob)
        except OSError:
            return 0
        return len(blob)

    def adopt(self, kind: str, key: str, nbytes: int) -> None:
        """Count an entry of `nbytes` that write() put in place (here or in another process) as this
        run's: kept from its evictions, and evicting others past the size cap. 0: nothing was written."""
        p = self.path(kind, key)
        if p is None or nbytes <= 0:
            return
        self._mine.add(p)
        if self.max_bytes is not None:
            with self._lock:
                if self._size is None:
                    self._size = self.size()
                self._size += nbytes
                over = self._size > self.max_bytes
            if over:
                self.evict(int(self.max_bytes * 0.9))

    def entries(self) -> list[tuple[Path, int, float]]:
        """(path, bytes, last use) of every entry."""
        if self.root is None or not self.root.is_dir():
            return []
        out = []
        for p in self.root.glob("*/*/*.npz"):
            try:
                st = p.stat()
            except OSError:
                continue
            out.append((p, st.st_size, st.st_mtime))
        return out

    def size(self) -> int:
        return sum(b for _, b, _ in self.entries())

    def evict(self, target_bytes: int) -> int:
        """Delete least recently used entries until at most target_bytes remain, never one this
        run wrote or read (it may still need it: store.PairStore reloads from here); returns how
        many were deleted."""
        entries = sorted((e for e in self.entries() if e[0] not in self._mine), key=lambda e: e[2])
        total_mine = sum(b for p, b, _ in self.entries() if p in self._mine)
        total = sum(b for _, b, _ in entries) + total_mine
        n = 0
        for p, b, _ in entries:
            if total <= target_bytes:
                break
            try:
                p.unlink()
                total -= b
                n += 1
            except OSError:
                pass
        with self._lock:
            self._size = total
        return n

    def clear(self) -> int:
        """Delete every entry (and the temporary files of interrupted writes); returns how many."""
        n = 0
        if self.root is None or not self.root.is_dir():
            return 0
        for p in list(self.root.glob("*/*/*.npz")) + list(self.root.glob("*/*/.tmp-*")):
            try:
                p.unlink()
                n += p.suffix == ".npz"
            except OSError:
                pass
        with self._lock:
            self._size = 0
        return n


def key(*parts: str) -> str:
    return digest("|".join([CODE_VERSION, *parts]))
