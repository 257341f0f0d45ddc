"""Reading the NumPy array files a user hands in (``.npy`` / ``.npz``: depth, masks, tracks, results, ground
truth): every way such a file can be unreadable (empty, not a NumPy file, cut short, pickled objects) becomes one
:class:`~trackingworld.errors.InputError` that names the file and the problem, never a traceback. numpy itself
reports a text file as "pickled data" and a truncated ``.npz`` as ``BadZipFile``; the file's first bytes say
which of the two formats it is, whatever its name."""

from __future__ import annotations

import os
import zipfile
from pathlib import Path

import numpy as np

from trackingworld.errors import InputError

NPY_MAGIC = b"\x93NUMPY"  # the first bytes of every .npy file (NumPy's format, version 1-3)
ZIP_MAGIC = b"PK"  # ... and of every .npz (a zip archive of .npy members; an empty one starts PK\x05\x06)


def read_arrays(path: str | os.PathLike, what: str) -> dict[str, np.ndarray]:
    """Every array in the file ``path``, read now: an ``.npz``'s members by name, an ``.npy``'s one array under
    the name ``""``. ``what`` names the file's role in the errors ("depth", "tracks", ...). Raises
    :class:`InputError` where the file is missing, empty, neither format, damaged or cut short, or holds object
    arrays (which would need pickle)."""
    path = Path(path)
    try:
        f = open(path, "rb")  # closed by the with below; an error of the open itself reported apart
    except OSError as e:
        raise InputError(f"{path}: cannot open the {what} file ({e.strerror or e})") from e
    with f:
        head = f.read(len(NPY_MAGIC))
        if not head:
            raise InputError(f"{path}: the {what} file is empty")
        if not (head.startswith(NPY_MAGIC) or head.startswith(ZIP_MAGIC)):
            raise InputError(f"{path}: the {what} file is not a NumPy .npy or .npz file (it starts with {head!r})")
        f.seek(0)
        try:  # np.load on an open file reads it by its content, whatever its name
            z = np.load(f, allow_pickle=False)
            if isinstance(z, np.ndarray):
                return {"": z}
            with z:
                return {k: z[k] for k in z.files}
        except (OSError, ValueError, EOFError, zipfile.BadZipFile, KeyError) as e:
            why = str(e) or type(e).__name__
            if "allow_pickle" in why:  # numpy's words for an object array
                raise InputError(f"{path}: the {what} file holds Python objects, not plain arrays (reading them "
                                 "would run pickle, which trackingworld does not do)") from e
            raise InputError(f"{path}: cannot read the {what} file: damaged or cut short ({why})") from e


def read_array(path: str | os.PathLike, what: str, key: str) -> np.ndarray:
    """The one array of an ``.npy`` file, or the member ``key`` of an ``.npz`` (its first member where it has no
    ``key``): :func:`read_arrays`' errors, and one where an ``.npz`` holds no array."""
    arrays = read_arrays(path, what)
    if not arrays:
        raise InputError(f"{path}: the {what} file holds no array")
    return arrays[key] if key in arrays else next(iter(arrays.values()))
