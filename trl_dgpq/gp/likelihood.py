"""Gaussian observation noise, a small module the GP model owns (``gp.likelihood``),
as GPyTorch's ``GaussianLikelihood``: y = f(x) + e, e ~ N(0, noise).
"""
from __future__ import annotations

import math
from typing import Sequence

import torch
from torch import nn

from .kernels import DTYPE


class GaussianLikelihood(nn.Module):
    """The observation-noise variance of each GP of a flat batch (``batch_shape (N,)``).

    State (both plain tensors of its ``state_dict``):
      ``noise``      buffer: the variances every GP computation uses -- exactly the value
                     given, or the last trained one.
      ``raw_noise``  Parameter: their logs, the coordinates gradient training moves (the
                     exact GP's ``neg_log_marginal_likelihood`` reads the noise as
                     ``exp(raw_noise)``). ``commit(rows)`` makes trained values the GPs'
                     noise; outside training ``raw_noise == log(noise)``.

    (The noise itself is kept because ``exp(log(v))`` is not always ``v`` to the last bit.)
    """

    def __init__(self, noise: float, batch_shape: Sequence[int] = (), dtype=DTYPE, device=None):
        super().__init__()
        noise = float(noise)
        if not math.isfinite(noise) or noise < 0:
            raise ValueError(f"noise_var must be finite and >= 0, got {noise}")
        self.batch_shape = torch.Size(batch_shape)
        self.register_buffer("noise", torch.full(self.batch_shape, noise, dtype=dtype, device=device))
        self.raw_noise = nn.Parameter(self.noise.log())

    @torch.no_grad()
    def commit(self, rows: torch.Tensor) -> None:
        """After training moved ``raw_noise``: GPs ``rows`` (flat indices) take the noise
        ``exp(raw_noise)``, and ``raw_noise`` is its log again."""
        self.noise[rows] = self.raw_noise[rows].exp()
        self.raw_noise[rows] = self.noise[rows].log()

    def extra_repr(self) -> str:
        return f"batch_shape={tuple(self.batch_shape)}"
