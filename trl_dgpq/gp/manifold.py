"""The manifold kernel (Calandra, Peters, Rasmussen & Deisenroth, 2016).

    k(x, x') = outputscale * exp(-|M(x) - M(x')|^2 / (2 lengthscale^2))

with M a small MLP. It is an RBF kernel on features, so every Gram matrix is
positive semi-definite by construction. Every GP of a batch has its own feature
map and hyperparameters (weights carry the flat GP dimension first), so seeds
never share parameters; ``forward``/``diag`` take the flat GP indices ``rows``
they are evaluated for (``per_gp = True`` tells the GP backends to pass them).

M(x) = x + W_out act(W_L ... act(W_1 x + b_1) ... + b_L) by default (``skip=True``):
with W_out initialised small, the kernel starts as the RBF kernel it replaces and
training bends the input space from there. ``skip=False`` gives the seed report's
plain map M(x) = act(W_L ... act(W_1 x + b_1) ...), whose features live in
(-1, 1)^h for tanh, so ``lengthscale`` is then in feature units.
"""
from __future__ import annotations

import math
from typing import Callable, Optional, Sequence

import torch
from torch import nn

from .kernels import DTYPE, ScaledKernel, sq_dist

ACTIVATIONS = {"tanh": torch.tanh, "softplus": nn.functional.softplus, "sigmoid": torch.sigmoid}


def _default_uniform(n: int, count: int) -> torch.Tensor:
    return torch.rand(n, count, generator=torch.Generator().manual_seed(0), dtype=DTYPE)


class ManifoldKernel(ScaledKernel):
    """RBF kernel on MLP features, one feature map per GP.

    num_gps: number of GPs (the flat size of the GP batch it serves).
    in_dim: input dimension; hidden: widths of the hidden layers (default one of 10).
    uniform: ``(num_gps, count) -> U[0, 1)`` source for the initial weights; pass
        per-seed streams (``trl_dgpq.rng.SeedStreams``) to keep seeds independent.
    """

    per_gp = True

    def __init__(self, num_gps: int, in_dim: int, hidden: Sequence[int] = (10,), lengthscale: float = 1.0,
                 outputscale: float = 1.0, activation: str = "tanh", skip: bool = True,
                 uniform: Optional[Callable[[int, int], torch.Tensor]] = None, dtype=DTYPE):
        super().__init__()
        hidden = tuple(int(h) for h in hidden)
        if not hidden or min(hidden) < 1:
            raise ValueError(f"hidden must be a non-empty list of positive widths, got {hidden}")
        if activation not in ACTIVATIONS:
            raise ValueError(f"activation must be one of {sorted(ACTIVATIONS)}, got {activation!r}")
        self.num_gps, self.in_dim, self.hidden, self.skip = int(num_gps), int(in_dim), hidden, bool(skip)
        self.act = ACTIVATIONS[activation]
        widths = (self.in_dim,) + hidden
        shapes = [((o, i), (o,)) for i, o in zip(widths[:-1], widths[1:])]
        if skip:
            shapes.append(((self.in_dim, hidden[-1]), None))
        count = sum(math.prod(w) + (math.prod(b) if b else 0) for w, b in shapes)
        u = (uniform or _default_uniform)(self.num_gps, count).to(dtype) * 2 - 1   # U(-1, 1)
        self.weights, self.biases = nn.ParameterList(), nn.ParameterList()
        at = 0
        for li, (wshape, bshape) in enumerate(shapes):
            last_skip = skip and li == len(shapes) - 1
            fan_in, fan_out = wshape[1], wshape[0]
            scale = 0.01 if last_skip else math.sqrt(6.0 / (fan_in + fan_out))  # Glorot uniform
            nw = math.prod(wshape)
            self.weights.append(nn.Parameter(u[:, at:at + nw].reshape(self.num_gps, *wshape) * scale))
            at += nw
            if bshape:
                self.biases.append(nn.Parameter(u[:, at:at + bshape[0]].clone()))
                at += bshape[0]
        self._init_scales(lengthscale, outputscale, (self.num_gps,), dtype)

    def _pick(self, p: torch.Tensor, rows) -> torch.Tensor:
        return p if rows is None else p[rows]

    def features(self, x: torch.Tensor, rows=None) -> torch.Tensor:
        """M(x): x ``(k, n, in_dim)`` for the GPs ``rows`` (k of them; None = all)."""
        h = x
        nb = len(self.biases)
        for li in range(nb):
            W, b = self._pick(self.weights[li], rows), self._pick(self.biases[li], rows)
            h = self.act(torch.baddbmm(b[:, None, :], h, W.mT))
        if self.skip:
            h = x + torch.bmm(h, self._pick(self.weights[nb], rows).mT)
        return h

    def forward(self, x1: torch.Tensor, x2: torch.Tensor, rows=None) -> torch.Tensor:
        ls = self._pick(self.lengthscale, rows)[:, None, None]
        f1 = self.features(x1, rows) / ls
        f2 = f1 if x2 is x1 else self.features(x2, rows) / ls
        return self._pick(self.outputscale, rows)[:, None, None] * torch.exp(sq_dist(f1, f2) * -0.5)

    def diag(self, x: torch.Tensor, rows=None) -> torch.Tensor:
        os_ = self._pick(self.outputscale, rows)
        return os_.view(-1, *([1] * (x.dim() - 2))).expand(x.shape[:-1])

    def extra_repr(self) -> str:
        return f"num_gps={self.num_gps}, in_dim={self.in_dim}, hidden={self.hidden}, skip={self.skip}"
