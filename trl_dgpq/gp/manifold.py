"""The manifold kernel (Calandra, Peters, Rasmussen & Deisenroth, 2016).

    k(x, x') = outputscale * exp(-|M(x) - M(x')|^2 / (2 lengthscale^2))

with M a small MLP. It is an RBF kernel on features, so every Gram matrix is
positive semi-definite by construction. The kernel has ``batch_shape (N,)``: each
of the N GPs of a flat batch has its own feature map and hyperparameters (every
parameter carries the GP dimension first), so seeds never share parameters. It is
called like every kernel (``trl_dgpq.gp.kernels``): ``k(x1, x2)`` on inputs with N
as their leading dim, or ``k.select(rows)(x1, x2)`` on a sub-batch.

M(x) = x + W_out act(W_L ... act(W_1 x + b_1) ... + b_L) by default (``skip=True``):
with W_out initialised small, the kernel starts as the RBF kernel it replaces and
training bends the input space from there. ``skip=False`` gives the seed report's
plain map M(x) = act(W_L ... act(W_1 x + b_1) ...), whose features live in
(-1, 1)^h for tanh, so ``lengthscale`` is then in feature units.
"""
from __future__ import annotations

import math
from typing import Callable, Optional, Sequence, Union

import torch
from torch import nn

from .kernels import DTYPE, Params, ScaledKernel

ACTIVATIONS = {"tanh": torch.tanh, "softplus": nn.functional.softplus, "sigmoid": torch.sigmoid}


def _default_uniform(n: int, count: int) -> torch.Tensor:
    return torch.rand(n, count, generator=torch.Generator().manual_seed(0), dtype=DTYPE)


class ManifoldKernel(ScaledKernel):
    """RBF kernel on MLP features, one feature map per GP.

    batch_shape: N or (N,), the number of GPs (the flat size of the GP batch it serves).
    in_dim: input dimension; hidden: widths of the hidden layers (default one of 10).
    uniform: ``(N, count) -> U[0, 1)`` source for the initial weights; pass
        per-seed streams (``trl_dgpq.rng.SeedStreams``) to keep seeds independent.

    Parameters (leading dim N): ``raw_lengthscale``, ``raw_outputscale``, the layer
    weights ``weight0``, ``weight1``, ... ``(N, out, in)``, with ``skip`` the output
    map ``skip_weight`` ``(N, in_dim, hidden[-1])``, and biases ``bias0``, ... ``(N, out)``.
    """

    def __init__(self, batch_shape: Union[int, Sequence[int]], in_dim: int, hidden: Sequence[int] = (10,),
                 lengthscale: float = 1.0, outputscale: float = 1.0, activation: str = "tanh", skip: bool = True,
                 uniform: Optional[Callable[[int, int], torch.Tensor]] = None, dtype=DTYPE):
        super().__init__(batch_shape)
        if len(self.batch_shape) != 1:
            raise ValueError("ManifoldKernel needs batch_shape (N,): one feature map per GP")
        hidden = tuple(int(h) for h in hidden)
        if not hidden or min(hidden) < 1:
            raise ValueError(f"hidden must be a non-empty list of positive widths, got {hidden}")
        if activation not in ACTIVATIONS:
            raise ValueError(f"activation must be one of {sorted(ACTIVATIONS)}, got {activation!r}")
        n, self.in_dim, self.hidden, self.skip = self.batch_shape[0], int(in_dim), hidden, bool(skip)
        self.act = ACTIVATIONS[activation]
        self._init_scales(lengthscale, outputscale, dtype)
        widths = (self.in_dim,) + hidden
        shapes = [((o, i), (o,)) for i, o in zip(widths[:-1], widths[1:])]
        if skip:
            shapes.append(((self.in_dim, hidden[-1]), None))
        count = sum(math.prod(w) + (math.prod(b) if b else 0) for w, b in shapes)
        u = (uniform or _default_uniform)(n, count).to(dtype) * 2 - 1   # U(-1, 1)
        weights, biases, at = [], [], 0
        for li, (wshape, bshape) in enumerate(shapes):
            last_skip = skip and li == len(shapes) - 1
            fan_in, fan_out = wshape[1], wshape[0]
            scale = 0.01 if last_skip else math.sqrt(6.0 / (fan_in + fan_out))  # Glorot uniform
            nw = math.prod(wshape)
            weights.append(u[:, at:at + nw].reshape(n, *wshape) * scale)
            at += nw
            if bshape:
                biases.append(u[:, at:at + bshape[0]].clone())
                at += bshape[0]
        self.depth = len(biases)
        for li, w in enumerate(weights):  # weights first, then biases: the parameters' order
            setattr(self, "skip_weight" if li == self.depth else f"weight{li}", nn.Parameter(w))
        for li, b in enumerate(biases):
            setattr(self, f"bias{li}", nn.Parameter(b))

    def features(self, x: torch.Tensor) -> torch.Tensor:
        """M(x) of every GP: x ``(N, n, in_dim)``."""
        return self._features(dict(self.named_parameters()), x)

    def _features(self, p: Params, x: torch.Tensor) -> torch.Tensor:
        h = x
        for li in range(self.depth):
            h = self.act(torch.baddbmm(p[f"bias{li}"][:, None, :], h, p[f"weight{li}"].mT))
        if self.skip:
            h = x + torch.bmm(h, p["skip_weight"].mT)
        return h

    def _gram(self, p: Params, x1: torch.Tensor, x2: torch.Tensor) -> torch.Tensor:
        return self._rbf(p, self._features(p, x1), None if x2 is x1 else self._features(p, x2))

    def extra_repr(self) -> str:
        return (f"batch_shape={tuple(self.batch_shape)}, in_dim={self.in_dim}, hidden={self.hidden}, "
                f"skip={self.skip}")
