"""Preconditioned conjugate gradients on torch tensors (any shape, any device), shared by stages 2 and 3."""

from __future__ import annotations

import warnings
from collections.abc import Callable

import torch


def sparse_csr(crow: torch.Tensor, cols: torch.Tensor, vals: torch.Tensor, shape: tuple[int, int]) -> torch.Tensor:
    """A torch CSR matrix from index tensors valid by construction, without torch's invariant check; torch's
    warnings that CSR is in beta and (2.11) that the check is off even when told so are silenced here."""
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message="Sparse invariant checks")
        warnings.filterwarnings("ignore", message="Sparse CSR tensor support is in beta")
        return torch.sparse_csr_tensor(crow, cols, vals, shape, check_invariants=False)


def pcg(matvec: Callable[[torch.Tensor], torch.Tensor], rhs: torch.Tensor,
        precond: Callable[[torch.Tensor], torch.Tensor], x0: torch.Tensor | None = None, iters: int = 500,
        tol: float = 1e-10, callback: Callable[[int, torch.Tensor], None] | None = None) -> torch.Tensor:
    """Solve ``A x = rhs`` for a symmetric positive definite A given as ``matvec``; ``precond`` applies an
    approximate inverse of A. Stops when ``|r| < tol |rhs|`` or after ``iters`` iterations; ``callback(it, x)``
    sees every iterate."""
    x = torch.zeros_like(rhs) if x0 is None else x0.clone()
    r = rhs - matvec(x) if x0 is not None else rhs.clone()
    z = precond(r)
    d = z.clone()
    rz = (r * z).sum()
    r0 = float(rhs.norm()) + 1e-30
    for it in range(iters):
        Ad = matvec(d)
        alpha = rz / (d * Ad).sum().clamp_min(1e-300)
        x = x + alpha * d
        r = r - alpha * Ad
        if callback:
            callback(it, x)
        if float(r.norm()) < tol * r0:
            break
        z = precond(r)
        rz_new = (r * z).sum()
        d = z + (rz_new / rz) * d
        rz = rz_new
    return x
