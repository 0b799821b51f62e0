"""Covariance functions with a batch shape, called one way, as in GPyTorch.

A kernel's ``batch_shape`` says how many sets of hyperparameters it holds:

* ``()``: one set, shared by every GP it serves; it broadcasts over any leading
  dims of the inputs.
* ``(N,)``: one set per GP of a flat batch of N; every parameter has N as its
  leading dim, and so must the inputs.

Every kernel is called the same way::

    K  = kernel(x1, x2)       # x1 (*b, n, d), x2 (*b, m, d) -> (*b, n, m)
    kd = kernel.diag(x)       # x (*b, n, d) -> (*b, n): k(x_i, x_i) without the matrix
    kr = kernel.select(rows)  # the kernel of the GPs ``rows`` (flat indices) only

``select`` is how a GP backend works on a gathered sub-batch of k GPs: for a
``(N,)`` kernel it gives a view with ``batch_shape (k,)`` whose parameters are
the gathered rows (gathered with autograd, so gradients reach the kernel's own
parameters, only the selected rows' of them); a shared ``()`` kernel returns
itself. Backends therefore never need to know which kind they hold.

A subclass registers its parameters (batch dims first) and writes its formulas
once, on a dict of parameter tensors: ``_gram(p, x1, x2)`` and ``_diag(p, x)``.
The kernel evaluates them on ``dict(self.named_parameters())``, a selection on
the gathered rows.
"""
from __future__ import annotations

import math
from typing import Dict, Optional, Sequence, Union

import torch
from torch import nn

DTYPE = torch.float64

Params = Dict[str, torch.Tensor]


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


class Kernel(nn.Module):
    """Base class of the kernels (see the module docstring)."""

    def __init__(self, batch_shape: Union[int, Sequence[int]] = ()):
        super().__init__()
        batch_shape = torch.Size([batch_shape] if isinstance(batch_shape, int) else batch_shape)
        if len(batch_shape) > 1 or any(b < 1 for b in batch_shape):
            raise ValueError(f"kernel batch_shape must be () (shared) or (N,) with N >= 1, got {tuple(batch_shape)}")
        self.batch_shape = batch_shape

    def forward(self, x1: torch.Tensor, x2: torch.Tensor) -> torch.Tensor:
        return self._gram(dict(self.named_parameters()), x1, x2)

    def diag(self, x: torch.Tensor) -> torch.Tensor:
        return self._diag(dict(self.named_parameters()), x)

    def select(self, rows: Optional[torch.Tensor]) -> Union["Kernel", "KernelRows"]:
        """The kernel of the GPs ``rows`` (1-D flat indices; None = all): a view with
        ``batch_shape (len(rows),)`` for a per-GP kernel, the kernel itself when shared."""
        if rows is None or not self.batch_shape:
            return self
        return KernelRows(self, rows)

    def _gram(self, p: Params, x1: torch.Tensor, x2: torch.Tensor) -> torch.Tensor:
        raise NotImplementedError

    def _diag(self, p: Params, x: torch.Tensor) -> torch.Tensor:
        raise NotImplementedError


class KernelRows:
    """``kernel.select(rows)``: the kernel of some GPs of a per-GP kernel. Called like
    a kernel; its parameters are the kernel's rows ``rows``, gathered once."""

    def __init__(self, kernel: Kernel, rows: torch.Tensor):
        if rows.dim() != 1:
            raise ValueError(f"rows must be 1-D flat GP indices, got shape {tuple(rows.shape)}")
        self.kernel = kernel
        self.batch_shape = torch.Size([rows.numel()])
        self.params = {name: p[rows] for name, p in kernel.named_parameters()}

    def __call__(self, x1: torch.Tensor, x2: torch.Tensor) -> torch.Tensor:
        return self.kernel._gram(self.params, x1, x2)

    def diag(self, x: torch.Tensor) -> torch.Tensor:
        return self.kernel._diag(self.params, x)


class ScaledKernel(Kernel):
    """Base of the RBF-type kernels: lengthscale and outputscale stored as logs
    (``raw_lengthscale``, ``raw_outputscale``, each of the kernel's batch_shape), so
    gradient-based fitting keeps them positive."""

    def _init_scales(self, lengthscale: float, outputscale: float, dtype=DTYPE) -> None:
        ls = math.log(_positive(lengthscale, "lengthscale"))
        os_ = math.log(_positive(outputscale, "outputscale"))
        self.raw_lengthscale = nn.Parameter(torch.full(self.batch_shape, ls, dtype=dtype))
        self.raw_outputscale = nn.Parameter(torch.full(self.batch_shape, os_, dtype=dtype))

    @property
    def lengthscale(self) -> torch.Tensor:
        return self.raw_lengthscale.exp()

    @property
    def outputscale(self) -> torch.Tensor:
        return self.raw_outputscale.exp()

    def _rbf(self, p: Params, f1: torch.Tensor, f2: Optional[torch.Tensor]) -> torch.Tensor:
        """outputscale * exp(-|f1 - f2|^2 / (2 lengthscale^2)) on the inputs or their
        features; ``f2`` None: the same tensor as ``f1`` (scaled once)."""
        ls, os_ = p["raw_lengthscale"].exp(), p["raw_outputscale"].exp()
        if ls.dim():  # one per GP, (k,), against inputs (k, n, d)
            ls, os_ = ls[:, None, None], os_[:, None, None]
        f1 = f1 / ls
        f2 = f1 if f2 is None else f2 / ls
        return os_ * torch.exp(sq_dist(f1, f2) * -0.5)

    def _diag(self, p: Params, x: torch.Tensor) -> torch.Tensor:
        os_ = p["raw_outputscale"].exp()
        if os_.dim():  # one per GP, (k,), against inputs (k, ..., d)
            os_ = os_.view(-1, *[1] * (x.dim() - 2))
        return os_.expand(x.shape[:-1])


class RBFKernel(ScaledKernel):
    """k(x, x') = outputscale * exp(-|x - x'|^2 / (2 lengthscale^2)); ``batch_shape ()``
    (default) shares one set of hyperparameters, ``(N,)`` gives each of N GPs its own."""

    def __init__(self, lengthscale: float = 1.0, outputscale: float = 1.0, batch_shape=(), dtype=DTYPE):
        super().__init__(batch_shape)
        self._init_scales(lengthscale, outputscale, dtype)

    def _gram(self, p: Params, x1: torch.Tensor, x2: torch.Tensor) -> torch.Tensor:
        return self._rbf(p, x1, x2)

    def extra_repr(self) -> str:
        if self.batch_shape:
            return f"batch_shape={tuple(self.batch_shape)}"
        return f"lengthscale={self.lengthscale.item():.4g}, outputscale={self.outputscale.item():.4g}"
