"""Delayed GP Q-learning (Grande, Walsh & How, ICML 2014, Algorithm 1), batched over seeds.

Every tensor has a leading seed dimension S; per-seed branches of the paper are
masks here. Per step t, with state s_t (names as in the paper):

    1. a_t = argmax_a Q̂_a(s_t), ties uniformly at random         -> act
    2. act, observe r_t, s_{t+1}                                    (environment)
    3. q_t = r_t + gamma max_a Q̂_a(s_{t+1})   (no bootstrap if terminal) -> q_target
    4. sigma1^2 = var GP_{a_t}(s_t); if > sigma_tol2: add (s_t, q_t)  -> learn_gp
    5. sigma2^2 = var GP_{a_t}(s_t)
    6. if sigma1^2 > sigma_tol2 >= sigma2^2 and Q̂_{a_t}(s_t) - mean GP_{a_t}(s_t) > 2 eps1:
         insert (s_t, mean + eps1) into Q̂_{a_t}, prune, reset every GP -> update_qhat

GP_a has prior mean Q̂_a: it is fed residuals q_t - Q̂_a(s_t), so its mean is
Q̂_a(s) + residual mean. Q̂ changes only in step 6, after which the GPs are
emptied, so stored residuals never go stale. Only the taken action's GP of each
seed is evaluated or updated (the GP backend gathers those rows).
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields
from typing import Optional, Sequence, Tuple

import torch

from .bounds import section5
from .gp import ExactGP, ManifoldKernel, RBFKernel, SparseOnlineGP
from .gp.train import fit
from .qhat import METRICS, LipschitzQ
from .rng import SeedStreams

GP_BACKENDS = {"exact": ExactGP, "sparse": SparseOnlineGP}
TIE_STREAM = 1  # the agent's random stream id (the env uses others)
KERNEL_STREAM = 3  # initial weights of manifold kernels
KERNELS = ("rbf", "manifold")


@dataclass
class DGPQConfig:
    """Hyperparameters of Algorithm 1. Give ``sigma_tol2`` and ``eps1`` directly, or
    leave them None and give ``eps``, ``delta`` and ``r_max`` to derive them by
    Section 5 (``resolve``)."""
    gamma: float = 0.01
    lipschitz: float = 1.0          # L_Q
    v_max: float = 2.0 / 0.99
    sigma_tol2: Optional[float] = 0.1
    eps1: Optional[float] = 0.001
    eps: Optional[float] = None     # Section 5 accuracy
    delta: Optional[float] = None   # Section 5 confidence
    r_max: Optional[float] = None
    noise_var: float = 0.1          # omega_n^2
    lengthscale: float = 0.05       # theta
    outputscale: float = 1.0        # s_f^2
    metric: str = "l1"
    gp: str = "sparse"
    budget: int = 100               # sparse GP basis vectors
    novelty_tol: float = 1e-3       # sparse GP novelty threshold
    capacity: int = 64              # initial storage (exact GP points, Q̂ pairs); grows
    kernel: str = "rbf"             # "manifold": RBF on MLP features, trained by NLL (exact GP only)
    kernel_hidden: Tuple[int, ...] = (10,)
    kernel_skip: bool = True        # M(x) = x + MLP(x): starts as the RBF kernel
    kernel_train_every: int = 20    # train a GP's kernel after this many new points ...
    kernel_min_points: int = 5      # ... if it then holds at least this many
    kernel_train_steps: int = 50    # Adam steps per training
    kernel_lr: float = 0.01

    def resolve(self, num_actions: int) -> "DGPQConfig":
        """Validate, derive Section 5 values where missing; returns self."""
        def bad(msg):
            raise ValueError(msg)
        finite = lambda v: v is not None and math.isfinite(v)  # noqa: E731
        if not (finite(self.gamma) and 0 <= self.gamma <= 1):
            bad(f"gamma must be in [0, 1], got {self.gamma}")
        for name in ("lipschitz", "noise_var", "lengthscale", "outputscale"):
            v = getattr(self, name)
            if not (finite(v) and v > 0):
                bad(f"{name} must be a finite number > 0, got {v}")
        if not finite(self.v_max):
            bad(f"v_max must be finite, got {self.v_max}")
        if self.metric not in METRICS:
            bad(f"metric must be one of {sorted(METRICS)}, got {self.metric!r}")
        if self.gp not in GP_BACKENDS:
            bad(f"gp must be one of {sorted(GP_BACKENDS)}, got {self.gp!r}")
        if int(self.budget) != self.budget or self.budget < 1:
            bad(f"budget must be a positive integer, got {self.budget}")
        if not (finite(self.novelty_tol) and self.novelty_tol >= 0):
            bad(f"novelty_tol must be >= 0, got {self.novelty_tol}")
        if self.kernel not in KERNELS:
            bad(f"kernel must be one of {KERNELS}, got {self.kernel!r}")
        self.kernel_hidden = tuple(int(h) for h in self.kernel_hidden)
        if self.kernel == "manifold":
            if self.gp != "exact":
                bad("kernel 'manifold' trains on the GP's data, which only gp 'exact' keeps: use --gp exact")
            if not self.kernel_hidden or min(self.kernel_hidden) < 1:
                bad(f"kernel_hidden must be positive widths, got {self.kernel_hidden}")
            for name in ("kernel_train_every", "kernel_min_points", "kernel_train_steps"):
                if int(getattr(self, name)) != getattr(self, name) or getattr(self, name) < 1:
                    bad(f"{name} must be a positive integer, got {getattr(self, name)}")
            if not (finite(self.kernel_lr) and self.kernel_lr > 0):
                bad(f"kernel_lr must be > 0, got {self.kernel_lr}")
        if self.sigma_tol2 is None or self.eps1 is None:
            if None in (self.eps, self.delta, self.r_max):
                bad("give sigma_tol2 and eps1, or eps, delta and r_max to derive them (Section 5)")
            eps1, sigma_tol2 = section5(self.eps, self.delta, self.gamma, self.r_max, self.lipschitz,
                                        num_actions, self.noise_var)
            self.eps1 = eps1 if self.eps1 is None else self.eps1
            self.sigma_tol2 = sigma_tol2 if self.sigma_tol2 is None else self.sigma_tol2
        if not (finite(self.sigma_tol2) and self.sigma_tol2 > 0):
            bad(f"sigma_tol2 must be > 0, got {self.sigma_tol2}")
        if not (finite(self.eps1) and self.eps1 >= 0):
            bad(f"eps1 must be >= 0, got {self.eps1}")
        return self

    @classmethod
    def from_dict(cls, d: dict) -> "DGPQConfig":
        names = {f.name for f in fields(cls)}
        unknown = set(d) - names
        if unknown:
            raise ValueError(f"unknown DGPQ settings: {sorted(unknown)}")
        return cls(**d)

    def to_dict(self) -> dict:
        return asdict(self)


def make_kernel(cfg: DGPQConfig, dim: int, seeds: Sequence[int], num_actions: int):
    """The config's kernel; a manifold kernel gets one feature map per (seed, action)
    GP, initialised from each seed's own random stream."""
    if cfg.kernel == "rbf":
        return RBFKernel(cfg.lengthscale, cfg.outputscale)
    streams = SeedStreams(seeds, stream=KERNEL_STREAM)
    uniform = lambda n, count: streams.uniform(num_actions * count).reshape(n, count)  # noqa: E731
    return ManifoldKernel(len(seeds) * num_actions, dim, cfg.kernel_hidden, cfg.lengthscale, cfg.outputscale,
                          skip=cfg.kernel_skip, uniform=uniform)


def make_gp(cfg: DGPQConfig, dim: int, batch_shape, kernel, device=None):
    """The GP backend named by ``cfg.gp`` with ``kernel`` and the config's noise."""
    extra = (dict(budget=cfg.budget, novelty_tol=cfg.novelty_tol) if cfg.gp == "sparse"
             else dict(capacity=cfg.capacity))
    return GP_BACKENDS[cfg.gp](kernel, cfg.noise_var, dim, batch_shape=batch_shape, device=device, **extra)


def argmax_random_ties(q: torch.Tensor, u: torch.Tensor) -> torch.Tensor:
    """Per row, a uniformly random index among the maxima of ``q`` (S, A), using the
    uniforms ``u`` (S, A) of each seed's own stream (never list order)."""
    top = q.amax(-1, keepdim=True)
    tied = q >= top - 1e-12 * top.abs().clamp_min(1.0)
    return torch.where(tied, u, -1.0).argmax(-1)


class DGPQ:
    """Algorithm 1 for S seeds at once (one Q̂ and |A| GPs per seed)."""

    def __init__(self, cfg: DGPQConfig, seeds: Sequence[int], state_dim: int, num_actions: int,
                 kernel=None, device=None):
        self.cfg = cfg.resolve(num_actions)
        self.S, self.A = len(seeds), num_actions
        self.qhat = LipschitzQ(self.S, num_actions, state_dim, cfg.lipschitz, cfg.v_max, cfg.metric,
                               capacity=cfg.capacity, device=device)
        kernel = kernel if kernel is not None else make_kernel(cfg, state_dim, seeds, num_actions)
        self.gp = make_gp(cfg, state_dim, (self.S, num_actions), kernel, device)
        self.trains_kernel = cfg.kernel == "manifold"
        self.since_fit = torch.zeros(self.S, num_actions, dtype=torch.long, device=device)
        self.kernel_fits = torch.zeros(self.S, dtype=torch.long, device=device)
        self.rng = SeedStreams(seeds, stream=TIE_STREAM, device=device)
        self.qhat_updates = torch.zeros(self.S, dtype=torch.long, device=device)
        self.gp_adds = torch.zeros(self.S, dtype=torch.long, device=device)
        self._memo = (None, -1, None)  # (state tensor, Q̂ version, Q̂ values)
        self._seeds = torch.arange(self.S, device=device)

    def qhat_values(self, s: torch.Tensor) -> torch.Tensor:
        """Q̂_a(s) for all actions, (S, A). Memoised on the state tensor and Q̂'s version:
        Q̂(s_{t+1}) of step 3 is Q̂(s_t) of the next step 1 and of step 6."""
        m_s, m_version, m_q = self._memo
        if s is m_s and m_version == self.qhat.version:
            return m_q
        q = self.qhat(s)
        self._memo = (s, self.qhat.version, q)
        return q

    # Step 1
    def act(self, s: torch.Tensor) -> torch.Tensor:
        """Greedy action on Q̂ with random tie-breaking. s (S, dim) -> (S,) long."""
        return argmax_random_ties(self.qhat_values(s), self.rng.uniform(self.A))

    # Step 3
    def q_target(self, r: torch.Tensor, s_next: torch.Tensor, terminal: torch.Tensor) -> torch.Tensor:
        bootstrap = self.qhat_values(s_next).amax(-1)
        return r + self.cfg.gamma * torch.where(terminal, torch.zeros_like(bootstrap), bootstrap)

    # Steps 4 and 5
    def learn_gp(self, s: torch.Tensor, residual: torch.Tensor, taken: torch.Tensor):
        """sigma1^2 = var GP_{a_t}(s_t); if > sigma_tol2, add (s_t, residual) to GP_{a_t};
        then the GP's residual mean and sigma2^2 at s_t. Each (S,), for the taken action."""
        x = s[:, None, :].expand(self.S, self.A, s.shape[-1])
        y = residual[:, None].expand(self.S, self.A)
        var1, mean2, var2, added = self.gp.add_if_uncertain(x, y, self.cfg.sigma_tol2, mask=taken)
        pick = lambda t: torch.where(taken, t, torch.zeros_like(t)).sum(-1)  # noqa: E731
        return pick(var1), pick(mean2), pick(var2), added.any(-1)

    # Step 6
    def update_qhat(self, s, a, mu, mask) -> None:
        m_s, m_version, m_q = self._memo
        self.qhat.insert(s, a, mu, mask)
        if m_s is not None and m_version == self.qhat.version - 1:
            # Pairs pruned by the insert were dominated by the new one, so the memoised
            # Q̂(s_{t+1}) only needs min(old, mu + L d(s_{t+1}, s_t)) for the new pair.
            new = torch.where(mask, self.qhat.bound(m_s, s, mu), torch.inf).clamp_max(self.cfg.v_max)
            q = m_q.clone()
            q[self._seeds, a] = torch.minimum(m_q[self._seeds, a], new)
            self._memo = (m_s, self.qhat.version, q)
        self.gp.reset(mask[:, None].expand(self.S, self.A))  # every action's GP of those seeds
        self.qhat_updates += mask

    def observe(self, s, a, r, s_next, terminal, active: Optional[torch.Tensor] = None) -> dict:
        """Steps 3-6 for the transition (s_t, a_t, r_t, s_{t+1}); ``active`` (S,) bool
        masks out seeds that are finished (they learn nothing)."""
        S = self.S
        active = torch.ones(S, dtype=torch.bool, device=s.device) if active is None else active
        s = s.to(torch.float64)
        qhat_sa = self.qhat_values(s).gather(1, a[:, None])[:, 0]  # before q_target: memo order
        q_t = self.q_target(r.to(torch.float64), s_next.to(torch.float64), terminal)
        taken = (a[:, None] == torch.arange(self.A, device=a.device)) & active[:, None]  # (S, A)
        if not active.any():
            none = torch.zeros(S, dtype=torch.bool, device=s.device)
            return dict(learn=none, update=none)
        var1, mean2, var2, learn = self.learn_gp(s, q_t - qhat_sa, taken)
        self.gp_adds += learn
        # Step 6: converged (sigma1^2 > sigma_tol2 >= sigma2^2) to a value clearly below Q̂
        update = learn & (var2 <= self.cfg.sigma_tol2) & (-mean2 > 2 * self.cfg.eps1)
        if self.trains_kernel:  # after the step-6 test, before its reset empties the GPs
            self.train_kernel(taken & learn[:, None])
        if update.any():
            self.update_qhat(s, a, qhat_sa + mean2 + self.cfg.eps1, update)
        return dict(learn=learn, update=update, var1=var1, var2=var2, mean2=mean2, q_target=q_t)

    def train_kernel(self, added: torch.Tensor) -> None:
        """Manifold kernel: once a GP has taken ``kernel_train_every`` new points since its
        last training and holds at least ``kernel_min_points``, fit its feature map and
        hyperparameters to the (s, residual) pairs it holds by NLL, and rebuild it."""
        self.since_fit += added
        due = (self.since_fit >= self.cfg.kernel_train_every) & (self.gp.size >= self.cfg.kernel_min_points)
        if due.any():
            fit(self.gp, due, steps=self.cfg.kernel_train_steps, lr=self.cfg.kernel_lr,
                min_points=self.cfg.kernel_min_points)
            self.since_fit[due] = 0
            self.kernel_fits += due.sum(-1)

    def episode_stats(self) -> dict:
        """Per-seed counters for the per-episode CSV, each (S,)."""
        stats = dict(qhat_size=self.qhat.size(), qhat_updates=self.qhat_updates,
                     gp_size=self.gp.size.sum(-1), gp_adds=self.gp_adds)
        if self.trains_kernel:
            stats["kernel_fits"] = self.kernel_fits
        return stats
