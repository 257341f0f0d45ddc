"""A cache of arrays in the output folder, keyed by everything they were computed from.

``cached(path, key, compute)`` returns the arrays stored at ``path`` when the key stored with them equals
``key``; otherwise it calls ``compute()``, stores the result (atomically) and returns it. Keys are JSON-able
dicts; :func:`file_identity` describes a file or folder by path, size and modification time (a model's files),
:func:`content_identity` an input by its content.
"""

from __future__ import annotations

import hashlib
import json
import os
import sys
import zipfile
from collections.abc import Callable
from pathlib import Path

import numpy as np

from trackingworld.io.atomic import atomic_path

# raised whenever a cached file would hold something else for the same key (2: the first-order upsampler)
CACHE_VERSION = 2


def file_identity(path: str | os.PathLike | None) -> dict | None:
    """Absolute path, size and mtime of a file, or of a folder's files (their count, total size, newest mtime)."""
    if not path:
        return None
    p = Path(path)
    if not p.exists():
        return {"spec": str(path)}
    if p.is_dir():
        files = [f for f in p.iterdir() if f.is_file()]
        return {"path": str(p.resolve()), "files": len(files), "bytes": sum(f.stat().st_size for f in files),
                "mtime_ns": max((f.stat().st_mtime_ns for f in files), default=0)}
    st = p.stat()
    return {"path": str(p.resolve()), "bytes": st.st_size, "mtime_ns": st.st_mtime_ns}


def content_identity(path: str | os.PathLike | None) -> dict | None:
    """An input file or folder by its content: the SHA-256 of its bytes (a folder's: of its files' names and bytes,
    in name order) and its size, not its path and times. The tracks and the priors made from them are then reused
    where the video was copied, moved or touched (a copied data folder has new times: 450 s of 2D tracking again on
    a 150-frame video, stop 86); hashing reads what the run decodes anyway (a 0.9 MB video: 7 ms)."""
    if not path:
        return None
    p = Path(path)
    if not p.exists():
        return {"spec": str(path)}
    h = hashlib.sha256()
    files = sorted(f for f in p.iterdir() if f.is_file()) if p.is_dir() else [p]
    size = 0
    for f in files:
        if p.is_dir():
            h.update(f.name.encode() + b"\0")
        with open(f, "rb") as fh:
            for block in iter(lambda fh=fh: fh.read(1 << 20), b""):
                h.update(block)
                size += len(block)
        h.update(b"\0")
    return {"sha256": h.hexdigest(), "bytes": size, **({"files": len(files)} if p.is_dir() else {})}


def _key_text(key: dict) -> str:
    return json.dumps({"cache_version": CACHE_VERSION, **key}, sort_keys=True, default=str)


def load_cached(path: Path, key: dict) -> dict[str, np.ndarray] | None:
    if not path.exists():
        return None
    try:
        with np.load(path, allow_pickle=False) as z:
            if "_key" not in z.files or str(z["_key"]) != _key_text(key):
                return None
            return {k: z[k] for k in z.files if k != "_key"}
    except (OSError, ValueError, zipfile.BadZipFile, KeyError):  # unreadable: recompute and overwrite
        return None


def cached(path: str | os.PathLike | None, key: dict, compute: Callable[[], dict[str, np.ndarray]],
           what: str = "", verbose: bool = True) -> dict[str, np.ndarray]:
    """Arrays from the cache file ``path`` if its key matches, else ``compute()`` (stored). ``path=None``:
    no caching."""
    if path is None:
        return compute()
    path = Path(path)
    hit = load_cached(path, key)
    if hit is not None:
        if verbose:
            print(f"[cache] {what or path.stem}: reusing {path}", file=sys.stderr)
        return hit
    arrays = compute()
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as f:
            np.savez(f, _key=np.array(_key_text(key)), **arrays)
    return arrays
