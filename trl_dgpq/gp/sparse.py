"""Sparse online GP (Csató & Opper 2002) with a basis-vector budget.

State per GP, with M = budget + 1 slots (one spare slot holds a new basis vector
until the deletion step decides which one goes): basis vectors BV ``(M, d)``,
alpha ``(M,)``, C ``(M, M)``, Q = K_BV^-1 ``(M, M)`` and the count n. C and Q are
stored interleaved as one ``(M, 2M)`` tensor, ``CQ[i, 2j] = C_ij``,
``CQ[i, 2j+1] = Q_ij``. Both are symmetric, so the row vector ``k^T CQ`` holds
``C k`` and ``Q k`` from one row-major pass (5x faster than a batched
matrix-vector product); each step's updates of both are one in-place rank-2
``baddbmm_``; and a GP using w slots lives in the contiguous-row block
``CQ[:w, :2w]``, so small GPs cost O(w^2), not O(M^2). Unused slots are all zero,
which makes every padded product vanish, so GPs of different sizes update
together:
    mean(x) = k_x^T alpha,    var(x) = k(x, x) + k_x^T C k_x.
Cost O(m^2) per point, flat in the number of points seen. The equations are those
of SPEC section 2.
"""
from __future__ import annotations

import torch

from .base import BatchedGP, State

# A point whose novelty is below this fraction of k(x, x) never extends the basis,
# whatever novelty_tol says, so (near-)duplicates cannot make Q ill-conditioned. At 1e-12
# a point 1e-5 lengthscales from a basis vector (novelty ~1e-10) still entered, and the
# posterior then missed a dense solve by 5e-5 (found by tests/test_properties.py). Below
# 1e-8 (within 1e-4 lengthscales) it is projected instead: exact for an exact duplicate,
# off by about its distance in lengthscales otherwise, and Q stays well conditioned.
DUPLICATE_RTOL = 1e-8


class SparseOnlineGP(BatchedGP):
    """Batched sparse online GP.

    budget: maximum number of basis vectors m per GP.
    novelty_tol: a point extends the basis when its novelty
        ``gamma = k(x,x) - k_x^T K_BV^-1 k_x`` exceeds this; otherwise it is absorbed by
        the projected (eta-corrected) update.
    When a GP holds m + 1 basis vectors, the one with the smallest KL score
    ``alpha_j^2 / (Q_jj + C_jj)`` is deleted.
    """

    _state_names = ("BV", "alpha", "CQ", "n")

    def __init__(self, kernel, noise_var, dim, batch_shape=(), budget: int = 100,
                 novelty_tol: float = 1e-3, **kw):
        if int(budget) != budget or budget < 1:
            raise ValueError(f"budget must be a positive integer, got {budget}")
        if not (float(novelty_tol) >= 0):
            raise ValueError(f"novelty_tol must be >= 0, got {novelty_tol}")
        self.budget = int(budget)
        self.novelty_tol = float(novelty_tol)
        super().__init__(kernel, noise_var, dim, batch_shape, **kw)
        if not (self.likelihood.noise > 0).all():
            raise ValueError("SparseOnlineGP needs noise_var > 0")

    @property
    def C(self) -> torch.Tensor:
        return self.CQ[:, :, 0::2]

    @property
    def Q(self) -> torch.Tensor:
        return self.CQ[:, :, 1::2]

    def _empty_state(self, k: int) -> State:
        M, kw = self.budget + 1, dict(dtype=self.dtype, device=self.device)
        return dict(
            BV=torch.zeros(k, M, self.dim, **kw),
            alpha=torch.zeros(k, M, **kw),
            CQ=torch.zeros(k, M, 2 * M, **kw),
            n=torch.zeros(k, dtype=torch.long, device=self.device),
        )

    def _width(self, n: torch.Tensor, adding: bool = False) -> int:
        # Slots beyond n are zero: the block CQ[:w, :2w] holds all of C and Q's non-zeros.
        M = self.budget + 1
        return max(1, min(M, int(n.max()) + int(adding)))

    def _narrow(self, name: str, t: torch.Tensor, width: int) -> torch.Tensor:
        return t[:, :width, :2 * width] if name == "CQ" else t[:, :width]

    def _clear(self, rows: torch.Tensor) -> None:
        w = self._width(self.n[rows])  # zeroing the used slots restores the empty state
        self.BV[rows, :w] = 0
        self.alpha[rows, :w] = 0
        self.CQ[:, :w, :2 * w][rows] = 0
        self.n[rows] = 0

    def _kx(self, st: State, x: torch.Tensor) -> torch.Tensor:
        """k(BV, x) ``(k, M, q)`` for x ``(k, q, d)``, zero on unused slots."""
        M = st["BV"].shape[1]
        used = torch.arange(M, device=x.device) < st["n"][:, None]
        return self._kernel(st)(st["BV"], x) * used[..., None]

    def _predict(self, st: State, xq: torch.Tensor):
        kx = self._kx(st, xq)                                          # (k, w, q)
        k, w, q = kx.shape
        mean = (kx * st["alpha"][..., None]).sum(-2)
        Ck = torch.bmm(kx.mT, st["CQ"][:, :w, :2 * w]).view(k, q, w, 2)[..., 0]  # (k, q, w)
        var = self._kernel(st).diag(xq) + (kx.mT * Ck).sum(-1)
        return mean, var

    # ------------------------------------------------------------- updates
    def _add(self, st: State, x: torch.Tensor, y: torch.Tensor, gate=None, force_project: bool = False):
        alpha, CQ, n = st["alpha"], st["CQ"], st["n"]
        k, w = alpha.shape   # w <= M slots in this (possibly narrowed) state
        M = self.budget + 1
        kx = self._kx(st, x[:, None])                                  # (k, w, 1)
        kxx = self._kernel(st).diag(x[:, None])[:, 0]                  # (k,)
        CQk = torch.bmm(kx.mT, CQ[:, :, :2 * w]).view(k, w, 2)         # (C k, Q k) interleaved
        Ck, e = CQk[..., 0], CQk[..., 1]
        kx = kx[..., 0]
        mean = (kx * alpha).sum(-1)
        var = kxx + (kx * Ck).sum(-1)
        learn = torch.ones_like(n, dtype=torch.bool) if gate is None else var > gate
        r = -1.0 / (self._noise(st) + var)
        q = (mean - y) * r
        gamma = (kxx - (kx * e).sum(-1)).clamp_min(0)                  # novelty
        # An empty GP always takes its first point as a basis vector; a duplicate never does.
        extend = ((gamma > self.novelty_tol) | (n == 0)) & (gamma > DUPLICATE_RTOL * kxx) & learn
        if force_project:
            extend = torch.zeros_like(extend)
        unit = (torch.arange(w, device=n.device) == n[:, None]).to(alpha.dtype)  # slot n
        ext = extend[:, None]
        # Projection: s = C k + e, scaled by eta = 1/(1 + gamma r). Extension: s = [C k; 1].
        s = Ck + torch.where(ext, unit, e)
        coef = torch.where(extend, 1.0, 1.0 / (1.0 + gamma * r)) * learn
        alpha.add_(s * (q * coef)[:, None])
        # C += r coef s s^T and, on extension, Q += e_hat e_hat^T / gamma with e_hat = [e; -1]:
        # one rank-2 update of [C, Q].
        e_hat = (e - unit) * ext
        inv_gamma = torch.where(extend, 1.0 / gamma.clamp_min(1e-300), 0.0)
        left = torch.stack((s, e_hat), -1)                             # (k, w, 2)
        right = torch.zeros(k, 2, w, 2, dtype=alpha.dtype, device=alpha.device)
        right[:, 0, :, 0] = s * (r * coef)[:, None]                    # -> C columns
        right[:, 1, :, 1] = e_hat * inv_gamma[:, None]                 # -> Q columns
        CQ[:, :, :2 * w].baddbmm_(left, right.view(k, 2, 2 * w))
        # Posterior at x: k_x^T s is var (extension) or var - gamma (projection).
        u = torch.where(extend, var, var - gamma)
        cu = coef * u
        mean_after, var_after = mean + q * cu, var + r * cu * u
        if extend.any():
            b = extend.nonzero().squeeze(-1)
            st["BV"][b, n[b]] = x[b]
            n += extend
            full = n > self.budget
            if full.any():
                self._delete(st, self._kl_argmin(st), full)
                mean_after, var_after = (v[:, 0] for v in self._predict(st, x[:, None]))
        return var, mean_after, var_after, learn

    @staticmethod
    def _kl_argmin(st: State) -> torch.Tensor:
        """Index of the basis vector with the smallest KL score alpha^2/(Q_jj + C_jj)."""
        M = st["alpha"].shape[1]
        CQ = st["CQ"]
        dc = CQ[:, :, 0::2].diagonal(dim1=-2, dim2=-1)
        dq = CQ[:, :, 1::2].diagonal(dim1=-2, dim2=-1)
        score = st["alpha"].square() / (dq + dc)
        used = torch.arange(M, device=score.device) < st["n"][:, None]
        return torch.where(used, score, torch.inf).argmin(-1)

    @staticmethod
    def _delete(st: State, j: torch.Tensor, which: torch.Tensor) -> None:
        """Remove basis vector ``j`` (per GP) from the GPs in ``which`` (bool mask)."""
        alpha, CQ, n, BV = st["alpha"], st["CQ"], st["n"], st["BV"]
        k, M = alpha.shape
        last = M - 1
        j = torch.where(which, j, torch.full_like(j, last))
        w = which.to(alpha.dtype)
        CQs = CQ.gather(1, j[:, None, None].expand(k, 1, 2 * M))[:, 0].view(k, M, 2)  # row j (symmetry)
        Cs, Qs = CQs[..., 0], CQs[..., 1]
        cs = Cs.gather(1, j[:, None])[:, 0]
        qs = Qs.gather(1, j[:, None])[:, 0]
        a_s = alpha.gather(1, j[:, None])[:, 0]
        one = torch.ones_like(qs)
        qs, qc = torch.where(which, qs, one), torch.where(which, qs + cs, one)
        # Exclude slot j itself from the correction ("all without row/col j").
        keep = torch.ones_like(alpha).scatter_(1, j[:, None], 0.0)
        Qs, QCs = Qs * keep, (Qs + Cs) * keep
        alpha.sub_(QCs * (w * a_s / qc)[:, None])
        # C += Q*Q*^T/q* - (Q*+C*)(Q*+C*)^T/(q*+c*),  Q -= Q*Q*^T/q*: one rank-2 update.
        left = torch.stack((Qs, QCs), -1)                                    # (k, M, 2)
        a, b = Qs * (w / qs)[:, None], QCs * (-w / qc)[:, None]
        right = torch.stack((torch.stack((a, -a), -1), torch.stack((b, torch.zeros_like(b)), -1)), 1)
        CQ.baddbmm_(left, right.view(k, 2, 2 * M))
        # Move the last slot into the freed slot j, then clear the last slot.
        CQ.scatter_(1, j[:, None, None].expand(k, 1, 2 * M), CQ[:, last:, :].clone())
        cols = torch.stack((2 * j, 2 * j + 1), 1)[:, None, :].expand(k, M, 2)
        CQ.scatter_(2, cols, CQ[:, :, 2 * last:].clone())
        CQ[:, last, :] = 0
        CQ[:, :, 2 * last:] = 0
        alpha.scatter_(1, j[:, None], alpha[:, last:].clone())
        alpha[:, last] = 0
        BV.scatter_(1, j[:, None, None].expand(k, 1, BV.shape[-1]), BV[:, last:].clone())
        BV[:, last] = 0
        n -= which.long()
