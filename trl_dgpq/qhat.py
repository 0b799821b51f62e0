"""The optimistic Lipschitz envelope Q̂ of DGPQ (GWH14, Eq. 7), batched over seeds.

For each seed and action a, Q̂ stores pairs (s_i, mu_i) and answers
    Q̂_a(s) = min(V_max, min_i [mu_i + L_Q * d(s, s_i)]).
An empty Q̂_a is V_max everywhere. Storage is ``capacity`` slots per seed and
action; an unused slot holds mu = +inf. Inserting into a full row doubles the
capacity (documented growth, a copy, amortised O(1)).

Layout, for a cost that follows the pairs held and not the storage: the R = S * A
rows are the last (contiguous) dimension, slots before them and state dimensions
first: states ``(dim, capacity, R)``, values ``(capacity, R)``. Slots [0, width) of
every row are then one contiguous block per state dimension, so evaluating Eq. 7
over them is a few elementwise passes over width * R numbers, with no copy.
(``cdist`` over ``(R, capacity, dim)`` storage had to copy a sliced block, or scan
the whole storage: time per step jumped after each doubling.)
"""
from __future__ import annotations

import math

import torch

METRICS = {"l1": 1.0, "l2": 2.0, "linf": math.inf}


def distance(x: torch.Tensor, s: torch.Tensor, metric: str) -> torch.Tensor:
    """d(x_b, s_bj): x ``(B, d)``, s ``(B, n, d)`` -> ``(B, n)``. ``cdist`` is ~10x faster
    than ``(x - s).abs().sum(-1)``, whose reduction runs over a tiny last dim."""
    return torch.cdist(x[:, None, :], s, p=METRICS[metric],
                       compute_mode="donot_use_mm_for_euclid_dist")[:, 0]


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
        R = num_seeds * num_actions
        self._s = torch.zeros(dim, capacity, R, **kw)
        # Unused slots hold mu = +inf: Eq. 7 needs no mask (mu + L d is +inf there).
        self._mu = torch.full((capacity, R), torch.inf, **kw)
        self.width = 0  # slots [0, width) may be used in some row; the rest are unused
        self.version = 0  # bumped by every change, for callers that memoise values

    @property
    def capacity(self) -> int:
        return self._mu.shape[0]

    @property
    def s(self) -> torch.Tensor:
        """Stored states, (S, A, capacity, dim) (a copy)."""
        return self._s.permute(2, 1, 0).reshape(self.S, self.A, self.capacity, self.dim)

    @property
    def mu(self) -> torch.Tensor:
        """Stored values, (S, A, capacity) (a copy); +inf in unused slots."""
        return self._mu.T.reshape(self.S, self.A, self.capacity)

    @property
    def valid(self) -> torch.Tensor:
        """Which slots hold a pair, (S, A, capacity)."""
        return torch.isfinite(self.mu)

    def size(self) -> torch.Tensor:
        """Stored pairs per seed, (S,)."""
        return torch.isfinite(self._mu[:self.width]).view(self.width, self.S, self.A).sum((0, 2))

    def _distances(self, x: torch.Tensor, w: int) -> torch.Tensor:
        """d(x_r, s_jr) for the first ``w`` slots of every row: x ``(R, dim)`` -> ``(w, R)``."""
        p = METRICS[self.metric]
        d = None
        for k in range(self.dim):
            term = (self._s[k, :w] - x[:, k]).abs_()
            if p == 2.0:
                term.square_()
            d = term if d is None else (torch.maximum(d, term, out=d) if p == math.inf else d.add_(term))
        return d.sqrt_() if p == 2.0 else d

    def __call__(self, x: torch.Tensor) -> torch.Tensor:
        """Q̂_a(x) for every action: x ``(S, dim)`` -> ``(S, A)``."""
        if self.width == 0:
            return x.new_full((self.S, self.A), self.v_max)
        w = self.width
        xs = x[:, None, :].expand(self.S, self.A, self.dim).reshape(self.S * self.A, self.dim)
        q = torch.add(self._mu[:w], self._distances(xs, w), alpha=self.lipschitz).amin(0)
        return q.view(self.S, self.A).clamp_max(self.v_max)

    def bound(self, x: torch.Tensor, s: torch.Tensor, mu: torch.Tensor) -> torch.Tensor:
        """mu + L d(x, s) for one pair per seed: x, s ``(S, dim)``, mu ``(S,)``."""
        return torch.add(mu, distance(x, s[:, None, :], self.metric)[:, 0], alpha=self.lipschitz)

    def insert(self, x: torch.Tensor, a: torch.Tensor, mu: torch.Tensor, mask: torch.Tensor) -> None:
        """Insert (x, mu) into Q̂_a for the seeds in ``mask`` and prune, per action, every
        stored pair it makes redundant (mu + L d(x, s_j) <= mu_j)."""
        seeds = mask.nonzero().squeeze(-1)
        if seeds.numel() == 0:
            return
        self.version += 1
        x, mu = x[seeds], mu[seeds]
        rows = seeds * self.A + a[seeds]                      # their rows of the storage
        w = self.width
        if w:
            s_r = self._s[:, :w, rows]                        # (dim, w, n)
            d = distance(x, s_r.permute(2, 1, 0), self.metric).T                      # (w, n)
            mu_r = self._mu[:w, rows]
            redundant = torch.add(mu[None, :], d, alpha=self.lipschitz) <= mu_r
            self._mu[:w, rows] = mu_r.masked_fill(redundant, torch.inf)
        if w == self.capacity and not torch.isinf(self._mu[:, rows]).any(0).all():
            self._grow()
        free = torch.isinf(self._mu[:w + 1, rows])            # slot w is free in every row
        slot = free.int().argmax(0)                           # first free slot
        self._s[:, slot, rows] = x.T
        self._mu[slot, rows] = mu
        self.width = max(w, int(slot.max()) + 1)

    def _grow(self) -> None:
        self._s = torch.cat((self._s, torch.zeros_like(self._s)), 1)
        self._mu = torch.cat((self._mu, torch.full_like(self._mu, torch.inf)), 0)

    def state_dict(self) -> dict:
        """Every field, including grown storage, ``width`` and ``version``; states as
        (S, A, capacity, dim) and values as (S, A, capacity), whatever the layout."""
        return {"s": self.s, "mu": self.mu, "width": self.width, "version": self.version}

    def load_state_dict(self, state: dict) -> None:
        s, mu = state["s"], state["mu"]
        if s.shape[:2] != (self.S, self.A) or s.shape[-1] != self.dim or mu.shape != s.shape[:-1]:
            raise ValueError(f"Q̂ state has shape {tuple(s.shape)}, expected ({self.S}, {self.A}, capacity, {self.dim})")
        R, cap = self.S * self.A, s.shape[2]
        self._s = s.to(dtype=self._s.dtype, device=self._s.device).reshape(R, cap, self.dim).permute(2, 1, 0).contiguous()
        self._mu = mu.to(dtype=self._mu.dtype, device=self._mu.device).reshape(R, cap).T.contiguous()
        self.width, self.version = int(state["width"]), int(state["version"])
