"""Atomic file writing: write to a temporary name beside the target, then rename."""

from __future__ import annotations

import contextlib
import json
import os
import tempfile
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from trackingworld.errors import InputError


def check_writable(folder: str | os.PathLike, what: str = "output folder") -> None:
    """Raise :class:`~trackingworld.errors.InputError` unless ``folder`` is, or can be made, a folder this process
    may write into: every part of it that exists a folder, the deepest of those writable. Nothing is created, so a
    run refused for its input leaves nothing behind; called before any work, so that the work is not lost at the
    end to a path that was never writable."""
    folder = Path(folder)
    for part in [folder, *folder.parents]:
        if part.exists() or part.is_symlink():
            if not part.is_dir():
                raise InputError(f"{folder}: cannot be the {what}: {part} is a file, not a folder")
            if not os.access(part, os.W_OK | os.X_OK):
                raise InputError(f"{folder}: cannot be the {what}: {part} is not writable")
            return


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike) -> Iterator[Path]:
    """Yield a temporary path in the target's folder; rename it to ``path`` only if the block succeeds."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp" + path.suffix, dir=path.parent)
    os.close(fd)
    tmp = Path(tmp)
    try:
        yield tmp
        tmp.chmod(0o666 & ~_umask())  # mkstemp makes it private; a result file is as readable as any other
        os.replace(tmp, path)
    finally:
        if tmp.exists():
            tmp.unlink()


@contextlib.contextmanager
def atomic_dir(path: str | os.PathLike) -> Iterator[Path]:
    """Yield a temporary folder beside ``path``; on success it replaces ``path`` (an older folder of that name is
    removed), on failure it is deleted, so a reader never sees a half-written folder."""
    import shutil

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent))
    try:
        yield tmp
        tmp.chmod(0o777 & ~_umask())
        if path.exists():
            old = path.with_name(f".{path.name}.old")
            shutil.rmtree(old, ignore_errors=True)
            os.replace(path, old)
            os.replace(tmp, path)
            shutil.rmtree(old, ignore_errors=True)
        else:
            os.replace(tmp, path)
    finally:
        if tmp.exists():
            shutil.rmtree(tmp, ignore_errors=True)


def write_text(path: str | os.PathLike, text: str) -> None:
    with atomic_path(path) as tmp:
        tmp.write_text(text)


def write_json(path: str | os.PathLike, obj) -> None:
    write_text(path, json.dumps(obj, indent=2, sort_keys=True, default=_json_default) + "\n")


NPZ_COMPRESSLEVEL = 1  # deflate level: float arrays barely compress further, and level 6 costs ~4x the time
# arrays of at least this many bytes are deflated in parts of NPZ_PART bytes on parallel threads (zlib lets go of
# the GIL), the parts' streams joined into one, as pigz does: each part but the last ends on a sync flush, which
# ends its blocks on a byte without ending the stream (a result of 30 frames at 854x480: docs/speed.md, stop 72)
NPZ_PARALLEL_BYTES = 32 << 20
NPZ_PART = 8 << 20


class _Deflated:
    """zipfile's compressor for a member whose deflate stream was made beforehand, part by part: ``compress`` is
    handed the parts in order (zipfile sums their CRC and size) and returns each one's stream."""

    def __init__(self, streams):
        self._streams = iter(streams)

    def compress(self, data) -> bytes:
        return next(self._streams)

    def flush(self) -> bytes:
        return b""


def _deflate_part(part: np.ndarray, last: bool) -> bytes:
    """The raw deflate stream of ``part`` (uint8), ending the stream where ``last``, else on a sync flush."""
    import zlib

    c = zlib.compressobj(NPZ_COMPRESSLEVEL, zlib.DEFLATED, -15)
    return c.compress(part) + c.flush(zlib.Z_FINISH if last else zlib.Z_SYNC_FLUSH)


def _write_member(zf, name: str, value, compress: bool) -> None:
    """One array as the member ``name`` of ``zf``, in numpy's .npy format; a large one deflated in parts on
    threads (:data:`NPZ_PARALLEL_BYTES`) where zipfile's writer takes a compressor, else by numpy and zipfile."""
    import io
    from concurrent.futures import ThreadPoolExecutor

    from trackingworld.optim.parallel import worker_threads

    arr = np.asanyarray(value)
    with zf.open(name, "w", force_zip64=True) as f:
        threads = worker_threads()
        if (not compress or arr.nbytes < NPZ_PARALLEL_BYTES or arr.dtype.hasobject or threads < 2
                or not hasattr(f, "_compressor")):
            np.lib.format.write_array(f, arr, allow_pickle=False)
            return
        arr = np.ascontiguousarray(arr)
        head = io.BytesIO()
        np.lib.format.write_array_header_1_0(head, np.lib.format.header_data_from_array_1_0(arr))
        raw = arr.reshape(-1).view(np.uint8)
        parts = [np.frombuffer(head.getvalue(), np.uint8)] + [raw[i:i + NPZ_PART] for i in range(0, len(raw),
                                                                                                   NPZ_PART)]
        with ThreadPoolExecutor(threads, thread_name_prefix="tw-deflate") as pool:
            f._compressor = _Deflated(pool.map(_deflate_part, parts, [k == len(parts) - 1 for k in
                                                                       range(len(parts))]))
            for part in parts:
                f.write(part)


def write_npz(path: str | os.PathLike, compress: bool = True, **arrays) -> None:
    """An ``.npz`` that ``np.load`` reads, written atomically; deflate at a low level when ``compress``."""
    import zipfile

    mode = zipfile.ZIP_DEFLATED if compress else zipfile.ZIP_STORED
    with atomic_path(path) as tmp:
        with zipfile.ZipFile(tmp, "w", compression=mode, compresslevel=NPZ_COMPRESSLEVEL if compress else None,
                             allowZip64=True) as zf:
            for key, value in arrays.items():
                _write_member(zf, f"{key}.npy", value, compress)


def _json_default(o):
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, Path):
        return str(o)
    raise TypeError(f"not JSON serialisable: {type(o)}")
