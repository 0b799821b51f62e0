"""Sparse online GP (Csató & Opper 2002) with a basis-vector budget.

State per GP, with M = budget + 1 slots (one spare slot holds a new basis vector
until the deletion step decides which one goes): basis vectors BV ``(M, d)``,
alpha ``(M,)``, C ``(M, M)``, Q = K_BV^-1 ``(M, M)`` and the count n. Unused slots
are all zero, which makes every padded product vanish, so GPs of different sizes
update together:
    mean(x) = k_x^T alpha,    var(x) = k(x, x) + k_x^T C k_x.
Every update is an in-place rank-1 (``baddbmm_``) on C and Q: O(m^2) per point,
flat in the number of points seen. The equations are those of SPEC section 2.
"""
from __future__ import annotations

import torch

from .base import BatchedGP, State

# A point whose novelty is below this fraction of k(x, x) never extends the basis,
# whatever novelty_tol says, so exact duplicates cannot make Q singular.
DUPLICATE_RTOL = 1e-12


class SparseOnlineGP(BatchedGP):
    """Batched sparse online GP.

    budget: maximum number of basis vectors m per GP.
    novelty_tol: a point extends the basis when its novelty
        ``gamma = k(x,x) - k_x^T K_BV^-1 k_x`` exceeds this; otherwise it is absorbed by
        the projected (eta-corrected) update.
    When a GP holds m + 1 basis vectors, the one with the smallest KL score
    ``alpha_j^2 / (Q_jj + C_jj)`` is deleted.
    """

    _state_names = ("BV", "alpha", "C", "Q", "n")

    def __init__(self, kernel, noise_var, dim, batch_shape=(), budget: int = 100,
                 novelty_tol: float = 1e-3, **kw):
        if int(budget) != budget or budget < 1:
            raise ValueError(f"budget must be a positive integer, got {budget}")
        if not (float(novelty_tol) >= 0):
            raise ValueError(f"novelty_tol must be >= 0, got {novelty_tol}")
        self.budget = int(budget)
        self.novelty_tol = float(novelty_tol)
        super().__init__(kernel, noise_var, dim, batch_shape, **kw)
        if self.noise_var == 0:
            raise ValueError("SparseOnlineGP needs noise_var > 0")

    def _empty_state(self, k: int) -> State:
        M, kw = self.budget + 1, dict(dtype=self.dtype, device=self.device)
        return dict(
            BV=torch.zeros(k, M, self.dim, **kw),
            alpha=torch.zeros(k, M, **kw),
            C=torch.zeros(k, M, M, **kw),
            Q=torch.zeros(k, M, M, **kw),
            n=torch.zeros(k, dtype=torch.long, device=self.device),
        )

    def _kx(self, st: State, x: torch.Tensor) -> torch.Tensor:
        """k(BV, x) ``(k, M, q)`` for x ``(k, q, d)``, zero on unused slots."""
        M = st["BV"].shape[1]
        used = torch.arange(M, device=x.device) < st["n"][:, None]
        return self.kernel(st["BV"], x) * used[..., None]

    def _predict(self, st: State, xq: torch.Tensor):
        kx = self._kx(st, xq)
        mean = (kx * st["alpha"][..., None]).sum(-2)
        var = self.kernel.diag(xq) + (kx * torch.bmm(st["C"], kx)).sum(-2)
        return mean, var

    # ------------------------------------------------------------- updates
    def _add(self, st: State, x: torch.Tensor, y: torch.Tensor, force_project: bool = False) -> None:
        alpha, C, Q, n = st["alpha"], st["C"], st["Q"], st["n"]
        M = alpha.shape[1]
        kx = self._kx(st, x[:, None])                                  # (k, M, 1)
        kxx = self.kernel.diag(x)                                      # (k,)
        Ck = torch.bmm(C, kx)[..., 0]
        e = torch.bmm(Q, kx)[..., 0]
        kx = kx[..., 0]
        mean = (kx * alpha).sum(-1)
        var = kxx + (kx * Ck).sum(-1)
        denom = self.noise_var + var
        q, r = (y - mean) / denom, -1.0 / denom
        gamma = (kxx - (kx * e).sum(-1)).clamp_min(0)                  # novelty
        # An empty GP always takes its first point as a basis vector.
        extend = ((gamma > self.novelty_tol) | (n == 0)) & (gamma > DUPLICATE_RTOL * kxx)
        if force_project:
            extend = torch.zeros_like(extend)
        unit = torch.nn.functional.one_hot(n.clamp_max(M - 1), M).to(alpha.dtype)
        ext = extend[:, None]
        # Projection: s = C k + e, scaled by eta = 1/(1 + gamma r). Extension: s = [C k; 1].
        s = Ck + torch.where(ext, unit, e)
        coef = torch.where(extend, torch.ones_like(gamma), 1.0 / (1.0 + gamma * r))
        alpha.add_(s * (q * coef)[:, None])
        C.baddbmm_(s[:, :, None], (s * (r * coef)[:, None])[:, None, :])
        if extend.any():
            e_hat = e - unit                                           # [e; -1]
            w = torch.where(extend, 1.0 / gamma.clamp_min(1e-300), torch.zeros_like(gamma))
            Q.baddbmm_(e_hat[:, :, None], (e_hat * w[:, None])[:, None, :])
            b = extend.nonzero().squeeze(-1)
            st["BV"][b, n[b]] = x[b]
            n += extend
            full = n > self.budget
            if full.any():
                self._delete(st, self._kl_argmin(st), full)

    @staticmethod
    def _kl_argmin(st: State) -> torch.Tensor:
        """Index of the basis vector with the smallest KL score alpha^2/(Q_jj + C_jj)."""
        M = st["alpha"].shape[1]
        dq = st["Q"].diagonal(dim1=-2, dim2=-1)
        dc = st["C"].diagonal(dim1=-2, dim2=-1)
        score = st["alpha"].square() / (dq + dc)
        used = torch.arange(M, device=score.device) < st["n"][:, None]
        return torch.where(used, score, torch.inf).argmin(-1)

    @staticmethod
    def _delete(st: State, j: torch.Tensor, which: torch.Tensor) -> None:
        """Remove basis vector ``j`` (per GP) from the GPs in ``which`` (bool mask)."""
        alpha, C, Q, n, BV = st["alpha"], st["C"], st["Q"], st["n"], st["BV"]
        k, M = alpha.shape
        last = M - 1
        j = torch.where(which, j, torch.full_like(j, last))
        w = which.to(alpha.dtype)
        col = j[:, None, None].expand(k, M, 1)
        Qs = Q.gather(2, col)[..., 0]
        Cs = C.gather(2, col)[..., 0]
        qs = Qs.gather(1, j[:, None])[:, 0]
        cs = Cs.gather(1, j[:, None])[:, 0]
        a_s = alpha.gather(1, j[:, None])[:, 0]
        one = torch.ones_like(qs)
        qs, qc = torch.where(which, qs, one), torch.where(which, qs + cs, one)
        # Exclude slot j itself from the correction ("all without row/col j").
        keep = torch.ones_like(alpha).scatter_(1, j[:, None], 0.0)
        Qs, QCs = Qs * keep, (Qs + Cs) * keep
        alpha.sub_(QCs * (w * a_s / qc)[:, None])
        # C += Qs Qs^T / q* - (Qs + Cs)(Qs + Cs)^T / (q* + c*) as one rank-2 update.
        left = torch.stack((Qs, QCs), -1)                                    # (k, M, 2)
        right = torch.stack((Qs * (w / qs)[:, None], QCs * (-w / qc)[:, None]), 1)  # (k, 2, M)
        C.baddbmm_(left, right)
        Q.baddbmm_(Qs[:, :, None], (Qs * (-w / qs)[:, None])[:, None, :])
        # Move the last slot into the freed slot j, then clear the last slot.
        row = j[:, None, None]
        for A in (C, Q):
            A.scatter_(1, row.expand(k, 1, M), A[:, last:, :].clone())
            A.scatter_(2, row.expand(k, M, 1), A[:, :, last:].clone())
            A[:, last, :] = 0
            A[:, :, last] = 0
        alpha.scatter_(1, j[:, None], alpha[:, last:].clone())
        alpha[:, last] = 0
        BV.scatter_(1, row.expand(k, 1, BV.shape[-1]), BV[:, last:].clone())
        BV[:, last] = 0
        n -= which.long()
