"""Block-tridiagonal linear systems: the normal equations of a whole window whose frames are coupled
only to their neighbours (:func:`mer_models.solver.ik.coupled_lm_ik`), solved by block cyclic
reduction, batched over samples.
"""

from __future__ import annotations

import torch

__all__ = ["block_tridiagonal_solve"]


def block_tridiagonal_solve(a: torch.Tensor, c: torch.Tensor, b: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Solve ``diag(c_{t-1}) x_{t-1} + a_t x_t + diag(c_t) x_{t+1} = b_t`` for all t.

    Block cyclic reduction: the odd frames are eliminated, the even ones form a system of the same
    shape (half the length), recursively; then the odd frames are recovered. ``log2 T`` levels,
    each batched over its frames, so a whole motion of thousands of frames costs a few dozen
    batched factorisations (the sequential block Thomas sweep would be T of them). For symmetric
    positive definite systems it is Cholesky of an odd-even permutation of the matrix: stable.

    Args:
        a: (B, T, n, n) symmetric positive definite diagonal blocks; c: (B, T-1, n) the diagonal
            blocks coupling frames t and t+1, or (B, T-1, n, n) dense ones (row t+1's block on
            x_t; row t's on x_{t+1} is its transpose); b: (B, T, n).

    Returns:
        x (B, T, n) and (B,) bool: every factorisation of that sample was positive definite
        (where not, its x is zero).
    """
    B, T, n = b.shape
    low = torch.zeros(B, T, *c.shape[2:], dtype=a.dtype, device=a.device)  # low[:, t]: row t's block on x_{t-1} (its diagonal)
    if T > 1:
        low[:, 1:] = c
    ok = torch.ones(B, dtype=torch.bool, device=a.device)
    x = _cyclic_reduction(a, low, b, ok)
    return torch.where(ok[:, None, None], x, torch.zeros_like(x)), ok


def _spd_inverse(a: torch.Tensor, ok: torch.Tensor) -> torch.Tensor:
    """Inverse of (B, K, n, n) SPD blocks; clears ``ok`` (B,) in place where a factorisation fails."""
    L, info = torch.linalg.cholesky_ex(a)
    bad = (info != 0).any(-1)
    if bool(bad.any()):  # keep the reduction finite; the sample's solution is dropped
        ok &= ~bad
        L = torch.where((info != 0)[..., None, None], torch.eye(a.shape[-1], dtype=a.dtype, device=a.device), L)
    return torch.cholesky_inverse(L)


def _cyclic_reduction(a: torch.Tensor, low: torch.Tensor, b: torch.Tensor, ok: torch.Tensor) -> torch.Tensor:
    """One level of :func:`block_tridiagonal_solve` on couplings ``low``: (B, T, n, n) dense blocks, or
    (B, T, n) the diagonals of diagonal ones (the first level; products with them are scalings,
    the same numbers as the dense products) (row t's block on x_{t-1}, ``low[:, 0] = 0``; row t's
    block on x_{t+1} is ``low[:, t+1]^T``)."""
    B, T, n = b.shape
    if T == 1:
        return (_spd_inverse(a, ok) @ b[..., None])[..., 0]
    diag = low.dim() == 3
    if T % 2:  # an uncoupled identity frame at the end makes the length even; its x is 0
        a = torch.cat([a, torch.eye(n, dtype=a.dtype, device=a.device).expand(B, 1, n, n)], 1)
        low = torch.cat([low, torch.zeros_like(low[:, :1])], 1)
        b = torch.cat([b, torch.zeros_like(b[:, :1])], 1)
    ae, ao, le, lo, be, bo = a[:, 0::2], a[:, 1::2], low[:, 0::2], low[:, 1::2], b[:, 0::2], b[:, 1::2]
    inv = _spd_inverse(ao, ok)  # (B, K, n, n): the odd frames, eliminated
    # even frame 2k: its left neighbour is odd frame 2k-1 (index k-1), its right one odd frame 2k+1 (index k)
    inv_l = torch.cat([torch.zeros_like(inv[:, :1]), inv[:, :-1]], 1)
    lo_l = torch.cat([torch.zeros_like(lo[:, :1]), lo[:, :-1]], 1)
    bo_l = torch.cat([torch.zeros_like(bo[:, :1]), bo[:, :-1]], 1)
    if diag:  # diag(l) @ X scales rows, X @ diag(l) columns
        le_inv = le[..., :, None] * inv_l
        up_inv = lo[..., :, None] * inv  # even row 2k's block on x_{2k+1} is diag(lo)
        a2 = ae - le_inv * le[..., None, :] - up_inv * lo[..., None, :]
        low2 = -(le_inv * lo_l[..., None, :])
    else:
        up = lo.transpose(-1, -2)  # even row 2k's block on x_{2k+1}
        le_inv = le @ inv_l
        up_inv = up @ inv
        a2 = ae - le_inv @ le.transpose(-1, -2) - up_inv @ lo
        low2 = -(le_inv @ lo_l)
    b2 = be - (le_inv @ bo_l[..., None])[..., 0] - (up_inv @ bo[..., None])[..., 0]
    xe = _cyclic_reduction(a2, low2, b2, ok)
    # odd frame 2k+1: b - low x_{2k} - (row's block on x_{2k+2}) x_{2k+2}
    le_r = torch.cat([le[:, 1:], torch.zeros_like(le[:, :1])], 1)  # row 2k+2's block on x_{2k+1}, transposed below
    xe_r = torch.cat([xe[:, 1:], torch.zeros_like(xe[:, :1])], 1)
    if diag:
        rhs = bo - lo * xe - le_r * xe_r
    else:
        rhs = bo - (lo @ xe[..., None])[..., 0] - (le_r.transpose(-1, -2) @ xe_r[..., None])[..., 0]
    xo = (inv @ rhs[..., None])[..., 0]
    x = torch.stack([xe, xo], 2).flatten(1, 2)
    return x[:, :T]
