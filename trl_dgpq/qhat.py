"""The optimistic Lipschitz envelope Q̂ of DGPQ (GWH14, Eq. 7), batched over seeds.

For each seed and action a, Q̂ stores pairs (s_i, mu_i) and answers
    Q̂_a(s) = min(V_max, min_i [mu_i + L_Q * d(s, s_i)]).
An empty Q̂_a is V_max everywhere. Storage is ``(S, A, capacity)`` slots with a
validity mask; inserting into a full row doubles the capacity (documented growth,
a copy, amortised O(1)).
"""
from __future__ import annotations

import math

import torch

METRICS = {"l1": 1.0, "l2": 2.0, "linf": math.inf}


def distance(x: torch.Tensor, s: torch.Tensor, metric: str) -> torch.Tensor:
    """d(x, s) over the last dim, broadcasting the rest."""
    diff = x - s
    if metric == "l1":  # the common case, kept to two cheap ops
        return diff.abs().sum(-1)
    return torch.linalg.vector_norm(diff, ord=METRICS[metric], dim=-1)


class LipschitzQ:
    """Q̂ for S seeds and A actions over ``dim``-dimensional states."""

    def __init__(self, num_seeds: int, num_actions: int, dim: int, lipschitz: float, v_max: float,
                 metric: str = "l1", capacity: int = 64, dtype=torch.float64, device=None):
        if metric not in METRICS:
            raise ValueError(f"metric must be one of {sorted(METRICS)}, got {metric!r}")
        if not (lipschitz > 0 and math.isfinite(lipschitz)):
            raise ValueError(f"lipschitz must be finite and > 0, got {lipschitz}")
        if not math.isfinite(v_max):
            raise ValueError(f"v_max must be finite, got {v_max}")
        self.S, self.A, self.dim = num_seeds, num_actions, dim
        self.lipschitz, self.v_max, self.metric = float(lipschitz), float(v_max), metric
        kw = dict(dtype=dtype, device=device)
        self.s = torch.zeros(num_seeds, num_actions, capacity, dim, **kw)
        self.mu = torch.zeros(num_seeds, num_actions, capacity, **kw)
        self.valid = torch.zeros(num_seeds, num_actions, capacity, dtype=torch.bool, device=device)
        self.width = 0  # slots [0, width) may be valid in some row; the rest are unused
        self._seeds = torch.arange(num_seeds, device=device)

    @property
    def capacity(self) -> int:
        return self.mu.shape[-1]

    def size(self) -> torch.Tensor:
        """Stored pairs per seed, (S,)."""
        return self.valid.sum((1, 2))

    def __call__(self, x: torch.Tensor) -> torch.Tensor:
        """Q̂_a(x) for every action: x ``(S, dim)`` -> ``(S, A)``."""
        w = self.width
        if w == 0:
            return x.new_full((self.S, self.A), self.v_max)
        d = distance(x[:, None, None, :], self.s[:, :, :w], self.metric)
        bound = torch.where(self.valid[:, :, :w], self.mu[:, :, :w] + self.lipschitz * d, torch.inf)
        return bound.amin(-1).clamp_max(self.v_max)

    def insert(self, x: torch.Tensor, a: torch.Tensor, mu: torch.Tensor, mask: torch.Tensor) -> None:
        """Insert (x, mu) into Q̂_a for the seeds in ``mask`` and prune, per action, every
        stored pair it makes redundant (mu + L d(x, s_j) <= mu_j)."""
        rows = mask.nonzero().squeeze(-1)
        if rows.numel() == 0:
            return
        x, a, mu = x[rows], a[rows], mu[rows]
        w = self.width
        if w:
            s_a, mu_a, valid_a = self.s[rows, a, :w], self.mu[rows, a, :w], self.valid[rows, a, :w]
            redundant = valid_a & (mu[:, None] + self.lipschitz * distance(x[:, None], s_a, self.metric) <= mu_a)
            self.valid[rows, a, :w] = valid_a & ~redundant
        free = ~self.valid[rows, a]
        if not free.any(-1).all():
            self._grow()
            free = ~self.valid[rows, a]
        slot = free.int().argmax(-1)  # first free slot
        self.s[rows, a, slot] = x
        self.mu[rows, a, slot] = mu
        self.valid[rows, a, slot] = True
        self.width = max(self.width, int(slot.max()) + 1)

    def _grow(self) -> None:
        cap = self.capacity
        pad = lambda t: torch.cat((t, torch.zeros_like(t)), 2)  # noqa: E731
        self.s, self.mu, self.valid = pad(self.s), pad(self.mu), pad(self.valid)
        assert self.capacity == 2 * cap

    def state_dict(self):
        return {"s": self.s, "mu": self.mu, "valid": self.valid}
