"""Exact GP regression with an incrementally bordered Cholesky factor.

State per GP (capacity ``c``): inputs X ``(c, d)``, targets Y ``(c,)``, the lower
Cholesky factor L of ``K + noise I`` ``(c, c)``, ``z = L^-1 y`` ``(c,)`` and the
count n. Unused rows of L are identity rows and unused entries of X, Y, z are 0, so
GPs of different sizes share one batched triangular solve:
    mean(x*) = (L^-1 k*)^T z,    var(x*) = k** - |L^-1 k*|^2.
Adding a point borders L with one row, ``l = L^-1 k_x``, ``d = sqrt(k_xx + noise - |l|^2)``:
O(n^2), never a re-factorisation.
"""
from __future__ import annotations

import math
from typing import Optional

import torch

from .base import BatchedGP, GPNumericalError, State

# Jitter ladder, relative to k(x, x): tried in order when a pivot is not positive.
JITTERS = (1e-10, 1e-8, 1e-6, 1e-4)


class ExactGP(BatchedGP):
    """Batched exact GP. ``capacity`` is the initial storage per GP; when a GP fills
    it, storage doubles (a copy, amortised O(1) per point). ``max_capacity`` (None =
    unbounded) turns growth past it into a clear error instead.

    Kernel training (``trl_dgpq.gp.fit``) needs only two public methods:
    ``neg_log_marginal_likelihood(mask)``, the differentiable loss, and
    ``refit(mask)``, which re-factorises GPs after their parameters changed."""

    _state_names = ("X", "Y", "L", "z", "n")

    def __init__(self, kernel, noise_var, dim, batch_shape=(), capacity: int = 1024,
                 max_capacity: Optional[int] = None, **kw):
        if int(capacity) != capacity or capacity < 1:
            raise ValueError(f"capacity must be a positive integer, got {capacity}")
        self.capacity = int(capacity)
        self.max_capacity = max_capacity
        super().__init__(kernel, noise_var, dim, batch_shape, **kw)

    def _empty_state(self, k: int) -> State:
        c, kw = self.capacity, dict(dtype=self.dtype, device=self.device)
        L = torch.zeros(k, c, c, **kw)
        L.diagonal(dim1=-2, dim2=-1).fill_(1.0)   # identity rows, made in place: no c x c temporary
        return dict(
            X=torch.zeros(k, c, self.dim, **kw),
            Y=torch.zeros(k, c, **kw),
            L=L,
            z=torch.zeros(k, c, **kw),
            n=torch.zeros(k, dtype=torch.long, device=self.device),
        )

    # ----------------------------------------------------------------- growth
    def growth_bytes(self) -> int:
        """Bytes the next add may allocate: a full GP has every GP's state made anew at twice the
        capacity c (X, Y and z double, L goes from c^2 to 4 c^2; 0 while all have room)."""
        if not self.n.numel() or int(self.n.max()) < self.capacity:
            return 0
        if self.max_capacity is not None and self.capacity >= self.max_capacity:
            return 0     # no growth: the add refuses the full GP instead
        c = 2 * self.capacity if self.max_capacity is None else min(2 * self.capacity, self.max_capacity)
        return self.num_gps * (self.X.element_size() * (c * self.dim + 2 * c + c * c) + self.n.element_size())

    def _prepare_add(self, rows) -> None:
        n = self.n if rows is None else self.n[rows]
        if n.numel() and int(n.max()) >= self.capacity:
            new = 2 * self.capacity
            if self.max_capacity is not None:
                if self.capacity >= self.max_capacity:
                    full = (self.n >= self.capacity).nonzero().squeeze(-1)
                    raise GPNumericalError(f"{self._gp_names(full)} is full "
                                           f"(max_capacity={self.max_capacity} points)")
                new = min(new, self.max_capacity)
            self._grow(new)

    def _load_from_state_dict(self, state_dict, prefix, *args, **kwargs):
        # A saved GP may have grown: take its capacity before the buffers are copied.
        X = state_dict.get(prefix + "X")
        if X is not None and X.shape[1] != self.capacity:
            self.capacity = X.shape[1]
            for k, t in self._empty_state(self.num_gps).items():
                setattr(self, k, t)
        super()._load_from_state_dict(state_dict, prefix, *args, **kwargs)

    def _grow(self, new: int) -> None:
        old = self.capacity
        self.capacity = new
        fresh = self._empty_state(self.num_gps)
        fresh["X"][:, :old] = self.X
        fresh["Y"][:, :old] = self.Y
        fresh["L"][:, :old, :old] = self.L
        fresh["z"][:, :old] = self.z
        fresh["n"] = self.n
        for k, t in fresh.items():
            setattr(self, k, t)

    # ------------------------------------------------------------- algebra
    def _add(self, st: State, x: torch.Tensor, y: torch.Tensor, gate=None):
        n = st["n"]
        m, L = self._block(st, int(n.max()) + 1)  # the used block plus the new row
        ar = torch.arange(m, device=n.device)
        k = self._kernel(st)
        kx = k(st["X"][:, :m], x[:, None])[..., 0] * (ar < n[:, None])
        # Identity padding keeps l zero beyond each GP's own n.
        l = torch.linalg.solve_triangular(L, kx[..., None], upper=False)[..., 0]
        kxx = k.diag(x[:, None])[:, 0]
        noise = self._noise(st)
        mean = (l * st["z"][:, :m]).sum(-1)
        var = kxx - l.square().sum(-1)
        learn = torch.ones_like(n, dtype=torch.bool) if gate is None else var > gate
        b = learn.nonzero().squeeze(-1)
        if b.numel():
            d2 = self._jitter(var[b] + noise[b], kxx[b], noise[b], learn)
            d = d2.sqrt()
            nb, lb = n[b], l[b]
            lb[torch.arange(b.numel(), device=b.device), nb] = d
            st["L"][b, nb, :m] = lb
            st["z"][b, nb] = (y[b] - mean[b]) / d
            st["X"][b, nb] = x[b]
            st["Y"][b, nb] = y[b]
            n += learn
            # Posterior at x from the new row: k_new = [l; var/d] against z_new = [z; z_n].
            gain = torch.zeros_like(var)
            gain[b] = var[b] / d2
            mean_after, var_after = mean + gain * (y - mean), var - gain * var
        else:
            mean_after, var_after = mean, var
        return var, mean_after, var_after, learn

    def _block(self, st: State, m: int):
        """Width and contiguous leading block of L covering ``m`` rows. A strided slice
        makes LAPACK copy and convert it (10x slower than the solve itself), so a
        nearly full factor is used whole: its identity padding keeps results exact."""
        cap = st["L"].shape[-1]
        if m > cap // 2:
            return cap, st["L"]
        return m, st["L"][:, :m, :m].contiguous()

    def _jitter(self, d2, kxx, noise, learn):
        floor = 1e-12 * (kxx + noise)
        bad = ~(d2 > floor)  # also catches NaN
        for j in JITTERS:
            if not bad.any():
                break
            d2 = torch.where(bad, d2 + j * kxx, d2)
            bad = ~(d2 > floor)
        if bad.any():
            raise GPNumericalError(f"Cholesky update failed even with jitter {JITTERS[-1]:g}*k(x,x) "
                                   f"in {self._gp_names(self._global_rows(learn.nonzero().squeeze(-1)[bad]))}")
        return d2

    def _predict(self, st: State, xq: torch.Tensor):
        n = st["n"]
        m = int(n.max()) if n.numel() else 0
        k = self._kernel(st)
        kqq = k.diag(xq)
        if m == 0:
            return torch.zeros_like(kqq), kqq.clone()
        m, L = self._block(st, m)
        ar = torch.arange(m, device=n.device)
        kx = k(st["X"][:, :m], xq) * (ar < n[:, None])[..., None]  # (k, m, q)
        v = torch.linalg.solve_triangular(L, kx, upper=False)
        mean = (v * st["z"][:, :m, None]).sum(-2)
        var = kqq - v.square().sum(-2)
        return mean, var

    # ------------------------------------------------------------ bulk fit
    @torch.no_grad()
    def set_data(self, x: torch.Tensor, y: torch.Tensor) -> None:
        """Replace every GP's data by ``x (*batch, n, dim)``, ``y (*batch, n)`` with one
        Cholesky factorisation (used to load data sets and after kernel changes)."""
        if x.dim() != len(self.batch_shape) + 2:
            raise ValueError(f"x must have shape (*batch_shape, n, dim), got {tuple(x.shape)}")
        npts = x.shape[-2]
        x = self._check(x, "x", (*self.batch_shape, npts, self.dim)).reshape(self.num_gps, npts, self.dim)
        y = self._check(y, "y", (*self.batch_shape, npts)).reshape(self.num_gps, npts)
        if self.max_capacity is not None and npts > self.max_capacity:
            raise GPNumericalError(f"{npts} points exceed max_capacity={self.max_capacity}")
        self.reset()
        if npts > self.capacity:
            self._grow(npts)
        self._factorise(torch.arange(self.num_gps, device=self.device), x, y)

    @torch.no_grad()
    def refit(self, mask: Optional[torch.Tensor] = None) -> None:
        """Re-factorise the selected GPs from their stored data with the kernel's and the
        likelihood's current parameters, e.g. after training changed them."""
        rows = self._rows(mask)
        rows = torch.arange(self.num_gps, device=self.device) if rows is None else rows
        for r in rows.tolist():  # GPs may hold different n: one factorisation each
            npts = int(self.n[r])
            if npts:
                self._factorise(torch.tensor([r], device=self.device),
                                self.X[r:r + 1, :npts].clone(), self.Y[r:r + 1, :npts].clone())

    def neg_log_marginal_likelihood(self, mask: Optional[torch.Tensor] = None):
        """Exact negative log marginal likelihood of each selected GP's stored data,

            NLL = 1/2 y^T (K + s^2 I)^-1 y + 1/2 log|K + s^2 I| + n/2 log(2 pi),

        differentiable with respect to the kernel's parameters and the likelihood's
        ``raw_noise`` (the noise enters as ``exp(raw_noise)``): the loss of kernel
        training. Each GP's loss involves only its own rows of per-GP parameters.
        Returns ``(nll, ok)``, each ``(k,)`` for the k GPs of ``mask`` (None: all) in
        row-major order; ``ok`` is False where the factorisation failed even with the
        jitter ladder, so that ``nll`` means nothing there.
        """
        rows = self._rows(mask)
        rows = torch.arange(self.num_gps, device=self.device) if rows is None else rows
        n = self.n[rows]
        m = int(n.max()) if rows.numel() else 0
        if m == 0:
            return n.to(self.dtype) * 0, torch.ones_like(n, dtype=torch.bool)
        X, Y = self.X[rows, :m], self.Y[rows, :m]
        valid = torch.arange(m, device=self.device) < n[:, None]
        k = self.kernel.select(rows)
        K = k(X, X)
        pair = valid[:, :, None] & valid[:, None, :]
        eye = torch.eye(m, dtype=K.dtype, device=K.device)
        noise = self.likelihood.raw_noise[rows].exp()
        # Padded rows/cols become identity, which adds exactly 0 to the NLL.
        K = torch.where(pair, K, 0.0) + eye * torch.where(valid, noise[:, None], 1.0)[:, :, None]
        L, info = cholesky_ladder(K, k.diag(X).amax(-1).detach())  # per-GP jitter
        z = torch.linalg.solve_triangular(L, (Y * valid)[..., None], upper=False)[..., 0]
        logdet = torch.where(valid, L.diagonal(dim1=-2, dim2=-1).clamp_min(1e-300).log(), 0.0).sum(-1)
        nll = 0.5 * z.square().sum(-1) + logdet + valid.sum(-1, dtype=K.dtype) * (0.5 * math.log(2 * math.pi))
        return nll, info == 0

    def _factorise(self, rows, x, y):
        npts = x.shape[-2]
        st = {"rows": rows}
        k = self._kernel(st)
        K = k(x, x)
        K.diagonal(dim1=-2, dim2=-1).add_(self._noise(st)[:, None])
        L = cholesky_jitter(K, k.diag(x).amax(-1), lambda bad: self._gp_names(rows[bad]))
        z = torch.linalg.solve_triangular(L, y[..., None], upper=False)[..., 0]
        self.X[rows, :npts] = x
        self.Y[rows, :npts] = y
        self.L[rows, :npts, :npts] = L
        self.z[rows, :npts] = z
        self.n[rows] = npts


def cholesky_ladder(K: torch.Tensor, scale: torch.Tensor):
    """Batched Cholesky, adding to each failing matrix the smallest jitter of the ladder
    (relative to ``scale``, shape batch) that makes it factorise; a matrix keeps the
    jitter that fixed it while others climb further. Returns (L, info); info > 0 marks
    matrices that failed even at the top of the ladder."""
    L, info = torch.linalg.cholesky_ex(K)
    jitter = torch.zeros_like(scale)
    eye = torch.eye(K.shape[-1], dtype=K.dtype, device=K.device)
    for j in JITTERS:
        bad = info > 0
        if not bad.any():
            break
        jitter = torch.where(bad, j * scale, jitter)
        L, info = torch.linalg.cholesky_ex(K + jitter[..., None, None] * eye)
    return L, info


def cholesky_jitter(K: torch.Tensor, scale: torch.Tensor, describe=lambda bad: "GP") -> torch.Tensor:
    """``cholesky_ladder`` that raises GPNumericalError naming the failing GPs instead of
    returning NaN."""
    if not torch.isfinite(K).all():
        bad = ~torch.isfinite(K).flatten(-2).all(-1)
        raise GPNumericalError(f"non-finite covariance in {describe(bad)}")
    L, info = cholesky_ladder(K, scale)
    bad = info > 0
    if bad.any():
        raise GPNumericalError(f"Cholesky failed even with jitter {JITTERS[-1]:g} in {describe(bad)}")
    return L
