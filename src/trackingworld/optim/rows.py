"""Rows of an array read in place (:class:`Rows`): the few observations a step uses of a subset of the tracks,
without copying the subset's every frame out of the pipeline's ``[N,T,...]`` arrays."""

from __future__ import annotations

import numpy as np


class Rows:
    """The rows ``rows [n]`` of an array ``array [M,...]`` read as an ``[n,...]`` array, without copying them out:
    ``Rows(a, rows)[key] == a[rows][key]`` for ``key`` an index, an index array, a boolean mask of the ``n`` rows or
    a tuple whose first item is one of those (``np.ix_``'s too). The rigid step reads the dynamic tracks' pixels and
    positions this way from the pipeline's arrays of every track (a copy of the dynamic ones: 20 bytes an
    observation at the step's peak), and the static fits and tests their tracks' pixels and prior at the
    observations they use (``optim.static_tests``: a copy of every frame of 131k tracks, 190 MB at 120 frames)."""

    def __init__(self, array: np.ndarray, rows: np.ndarray):
        self.array, self.rows = array, np.asarray(rows)
        self.shape = (len(self.rows),) + array.shape[1:]
        self.dtype = array.dtype

    def __len__(self) -> int:
        return len(self.rows)

    def of(self, idx) -> np.ndarray:
        """The rows of ``array`` that index ``idx`` (as above, or a slice) of these rows takes."""
        if isinstance(idx, slice):
            return self.rows[idx]
        idx = np.asarray(idx)
        return self.rows[np.flatnonzero(idx) if idx.dtype == np.bool_ else idx]

    def __getitem__(self, key):
        if isinstance(key, tuple):
            return self.array[(self.of(key[0]),) + key[1:]]
        return self.array[self.of(key)]

    def copy(self) -> np.ndarray:
        """``array[rows]``: the rows copied out."""
        return self.array[self.rows]
