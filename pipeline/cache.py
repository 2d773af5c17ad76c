"""On-disk cache of per-pair results, keyed by image content and parameters.

Entries are .npz files written atomically (temporary file + rename), so an interrupted run never
leaves a half-written entry. Maps are stored as float16 and every result, fresh or cached, goes
through the same quantisation, so a cached run gives exactly the maps of a cold run.
"""

from __future__ import annotations

import dataclasses
import io
import json
import os
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

from .params import digest

CODE_VERSION = "10"      # bump when a change alters per-pair results


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


def to_bytes(obj: Any, float16: tuple[str, ...] = ()) -> bytes:
    arrays: dict[str, np.ndarray] = {}
    meta: dict[str, Any] = {}
    _flatten(obj, "", arrays, meta)
    for k in float16:
        arrays[k] = arrays[k].astype(np.float16)
    buf = io.BytesIO()
    np.savez_compressed(buf, __meta__=np.frombuffer(json.dumps(meta).encode(), np.uint8), **arrays)
    return buf.getvalue()


def from_bytes(cls: type, data: bytes, float32: tuple[str, ...] = ()) -> Any:
    with np.load(io.BytesIO(data), allow_pickle=False) as z:
        meta = json.loads(bytes(z["__meta__"]).decode())
        arrays = {k: z[k] for k in z.files if k != "__meta__"}
    for k in float32:
        arrays[k] = arrays[k].astype(np.float32)
    return _unflatten(cls, "", arrays, meta)


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


class PairCache:
    """Get/put serialised dataclasses by key. `root=None` disables caching."""

    def __init__(self, root: Path | None):
        self.root = Path(root) if root is not None else None
        self.hits = 0
        self.misses = 0

    def path(self, kind: str, key: str) -> Path | None:
        return None if self.root is None else self.root / kind / key[:2] / f"{key}.npz"

    def get(self, kind: str, key: str) -> bytes | None:
        p = self.path(kind, key)
        if p is None or not p.exists():
            self.misses += 1
            return None
        try:
            data = p.read_bytes()
        except OSError:
            self.misses += 1
            return None
        self.hits += 1
        return data

    def put(self, kind: str, key: str, data: bytes) -> None:
        p = self.path(kind, key)
        if p is None:
            return
        try:
            atomic_write_bytes(p, data)
        except OSError:
            pass      # a cache that cannot be written only costs time


def key(*parts: str) -> str:
    return digest("|".join([CODE_VERSION, *parts]))
