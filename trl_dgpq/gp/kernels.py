"""Covariance functions: small modules with ``forward(x1, x2)`` as in GPyTorch.

``x1`` is ``(..., n, d)``, ``x2`` is ``(..., m, d)`` and ``forward`` returns the
``(..., n, m)`` Gram matrix, batched over the leading dims. ``diag(x)`` returns
``k(x_i, x_i)`` as ``(..., n)`` without building the matrix.
"""
from __future__ import annotations

import math

import torch
from torch import nn

DTYPE = torch.float64


def _positive(value: float, name: str) -> float:
    value = float(value)
    if not math.isfinite(value) or value <= 0:
        raise ValueError(f"{name} must be a finite positive number, got {value}")
    return value


def sq_dist(x1: torch.Tensor, x2: torch.Tensor) -> torch.Tensor:
    """Squared Euclidean distances ``(..., n, m)``.

    Uses the direct (difference) form rather than ``|a|^2 + |b|^2 - 2ab``: the
    latter loses all digits for nearby points, which is where GP algebra needs them.
    """
    return torch.cdist(x1, x2, compute_mode="donot_use_mm_for_euclid_dist").square()


class ScaledKernel(nn.Module):
    """Base of the RBF-type kernels: lengthscale and outputscale stored as logs
    (``raw_lengthscale``, ``raw_outputscale``), so gradient-based fitting keeps them
    positive; ``shape`` () for one shared value, (num_gps,) for one per GP."""

    def _init_scales(self, lengthscale: float, outputscale: float, shape=(), dtype=DTYPE) -> None:
        ls = math.log(_positive(lengthscale, "lengthscale"))
        os_ = math.log(_positive(outputscale, "outputscale"))
        self.raw_lengthscale = nn.Parameter(torch.full(shape, ls, dtype=dtype))
        self.raw_outputscale = nn.Parameter(torch.full(shape, os_, dtype=dtype))

    @property
    def lengthscale(self) -> torch.Tensor:
        return self.raw_lengthscale.exp()

    @property
    def outputscale(self) -> torch.Tensor:
        return self.raw_outputscale.exp()


class RBFKernel(ScaledKernel):
    """k(x, x') = outputscale * exp(-|x - x'|^2 / (2 lengthscale^2)), one shared set of
    hyperparameters for every GP it serves."""

    def __init__(self, lengthscale: float = 1.0, outputscale: float = 1.0, dtype=DTYPE):
        super().__init__()
        self._init_scales(lengthscale, outputscale, (), dtype)

    def forward(self, x1: torch.Tensor, x2: torch.Tensor) -> torch.Tensor:
        ls = self.lengthscale
        return self.outputscale * torch.exp(sq_dist(x1 / ls, x2 / ls) * -0.5)

    def diag(self, x: torch.Tensor) -> torch.Tensor:
        return self.outputscale.expand(x.shape[:-1])

    def extra_repr(self) -> str:
        return f"lengthscale={self.lengthscale.item():.4g}, outputscale={self.outputscale.item():.4g}"
