"""Delayed GP Q-learning (Grande, Walsh & How, ICML 2014, Algorithm 1), batched over seeds.

Every tensor has a leading seed dimension S; per-seed branches of the paper are
masks here. Per step t, with state s_t (names as in the paper):

    1. a_t = argmax_a Q̂_a(s_t), ties uniformly at random         -> act
    2. act, observe r_t, s_{t+1}                                    (environment)
    3. q_t = r_t + gamma max_a Q̂_a(s_{t+1})   (no bootstrap if terminal) -> q_target
       (the variant slack="once": gamma (max_a Q̂_a(s_{t+1}) - eps1))
    4. sigma1^2 = var GP_{a_t}(s_t); if > sigma_tol2: add (s_t, q_t)  -> learn_gp
    5. sigma2^2 = var GP_{a_t}(s_t)
    6. if sigma1^2 > sigma_tol2 >= sigma2^2 and Q̂_{a_t}(s_t) - mean GP_{a_t}(s_t) > 2 eps1:
         insert (s_t, mean + eps1) into Q̂_{a_t}, prune, reset every GP -> update_qhat

GP_a has prior mean Q̂_a: it is fed residuals q_t - Q̂_a(s_t), so its mean is
Q̂_a(s) + residual mean. Q̂ changes only in step 6, after which the GPs are
emptied, so stored residuals never go stale. Only the taken action's GP of each
seed is evaluated or updated (the GP backend gathers those rows).

As an agent of the runner (``trl_dgpq.agents``), ``act(td)`` and ``observe(td,
active)`` read the TensorDicts of a TorchRL env and call ``select_action`` (step
1) and ``learn`` (steps 3-6).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Optional, Sequence, Tuple

import torch

from .agents.base import learning_reward
from .bounds import box_covering, section5, unit_square_covering
from .config import check_config, nested, setting
from .gp import GPConfig, fit, make_gp, make_kernel
from .qhat import METRICS, LipschitzQ
from .rng import TIE_STREAM, SeedStreams
from .tuning import LogUniform

COVERINGS = ("env", "unit-square")
SLACKS = ("algorithm-1", "once")


@dataclass
class DGPQConfig:
    """Delayed GP Q-learning (GWH14, Algorithm 1). Give ``sigma_tol2`` and ``eps1``
    directly, or set them to none and give ``eps``, ``delta`` and ``r_max`` to derive
    them by Section 5 (``resolve``)."""
    gamma: float = setting(0.01, "discount gamma", within="[0, 1]")
    lipschitz: float = setting(1.0, "Lipschitz constant L_Q of the envelope Q̂ (Eq. 7)", within="(0, inf)")
    v_max: float = setting(2.0 / 0.99, "V_max, the value of Q̂ where nothing is known", within="(-inf, inf)")
    sigma_tol2: Optional[float] = setting(0.1, "variance threshold sigma_tol^2 (none: derive by Section 5)",
                                          within="(0, inf)")
    eps1: Optional[float] = setting(0.001, "optimism margin epsilon_1 (none: derive by Section 5)",
                                    within="[0, inf)")
    eps: Optional[float] = setting(None, "Section 5 accuracy epsilon (given alone, derives sigma_tol2 and eps1)",
                                   within="(0, inf)")
    delta: Optional[float] = setting(None, "Section 5 confidence delta", within="(0, 1)")
    r_max: Optional[float] = setting(None, "Section 5 R_max", within="(0, inf)")
    slack: str = setting("algorithm-1", "where eps1's margin goes: algorithm-1 (step 3 bootstraps on Q̂(s'), so "
                                        "each overwrite adds eps1 to the margins Q̂(s') carries: at gamma 1 at least "
                                        "K eps1 over K steps) or once (a variant, not GWH14: step 3 bootstraps on "
                                        "Q̂(s') - eps1, so an overwrite adds none; docs/domains/liquidation.md)",
                         choices=SLACKS)
    covering: str = setting("env", "Section 5 covering number N_S: env (from the env's state box and the "
                                   "metric) or unit-square (the seed report's ceil(1/(pi r^2)))", choices=COVERINGS)
    metric: str = setting("l1", "state metric d of Q̂", choices=tuple(METRICS))
    qhat_capacity: int = setting(64, "initial Q̂ storage, pairs per seed and action (doubles when full)",
                                 within="[1, inf)")
    state_scale: Tuple[float, ...] = setting((), "weights multiplying the observation's dimensions before "
                                                 "Q̂ and the GPs see them; 0 drops a dimension (empty: as is)",
                                             within="[0, inf)")
    gp: GPConfig = nested(GPConfig)
    kernel_train_every: int = setting(20, "manifold: train a GP's kernel after this many new points ...",
                                      within="[1, inf)")
    kernel_min_points: int = setting(5, "manifold: ... if the GP then holds at least this many", within="[1, inf)")
    kernel_train_steps: int = setting(50, "manifold: Adam steps per training", within="[1, inf)")
    kernel_lr: float = setting(0.01, "manifold: Adam learning rate", within="(0, inf)")

    KERNEL_TRAINING = ("kernel_train_every", "kernel_min_points", "kernel_train_steps", "kernel_lr")

    @classmethod
    def upgrade(cls, d: dict) -> dict:
        """A recorded config (``to_dict`` form) in today's layout: configs written before
        the kernel training schedule moved here from GPConfig hold it under ``gp``."""
        gp = d.get("gp")
        old = [k for k in cls.KERNEL_TRAINING if k in gp] if isinstance(gp, dict) else []
        if not old:
            return d
        d, gp = dict(d), dict(gp)
        for k in old:
            if k in d:
                raise ValueError(f"{k} is given twice, as {k} and (in the old layout) as gp.{k}")
            d[k] = gp.pop(k)
        d["gp"] = gp
        return d

    @staticmethod
    def implied(given: dict) -> dict:
        """Asking for Section 5 (eps or delta) without sigma_tol2 / eps1 derives both."""
        if {"eps", "delta"} & set(given):
            return {k: None for k in ("sigma_tol2", "eps1") if k not in given}
        return {}

    def cross_check(self) -> None:
        if self.state_scale and not any(self.state_scale):
            raise ValueError(f"state_scale must be weights >= 0, not all 0, got {list(self.state_scale)}")

    def resolve(self, num_actions: int, state_box=None) -> "DGPQConfig":
        """Check, and derive Section 5 values where missing (checking them too); returns
        self. ``state_box`` (low, high) gives the covering number when ``covering`` is "env"."""
        check_config(self)
        if self.sigma_tol2 is None or self.eps1 is None:
            if None in (self.eps, self.delta, self.r_max):
                raise ValueError("give sigma_tol2 and eps1, or eps, delta and r_max to derive them (Section 5)")
            if self.covering == "unit-square":
                covering = unit_square_covering
            elif state_box is None:
                raise ValueError("Section 5 with covering 'env' needs the env's state box")
            else:
                covering = box_covering(*state_box, self.metric)
            eps1, sigma_tol2 = section5(self.eps, self.delta, self.gamma, self.r_max, self.lipschitz,
                                        num_actions, self.gp.noise_var, covering)
            self.eps1 = eps1 if self.eps1 is None else self.eps1
            self.sigma_tol2 = sigma_tol2 if self.sigma_tol2 is None else self.sigma_tol2
            check_config(self)
        return self


# What `trl-dgpq tune` searches (trl_dgpq/tuning.py): the GP's lengthscale and noise omega_n^2, Q̂'s L_Q,
# and Algorithm 1's sigma_tol^2 and eps1 (given, so Section 5 derives nothing).
SEARCH_SPACE = {
    "lengthscale": LogUniform(0.01, 1.0),
    "lipschitz": LogUniform(0.1, 100.0),
    "sigma_tol2": LogUniform(1e-4, 0.5),
    "eps1": LogUniform(1e-4, 0.1),
    "noise_var": LogUniform(1e-3, 1.0),
}


def argmax_random_ties(q: torch.Tensor, u: torch.Tensor) -> torch.Tensor:
    """Per row, a uniformly random index among the maxima of ``q`` (S, A), using the
    uniforms ``u`` (S, A) of each seed's own stream (never list order)."""
    top = q.amax(-1, keepdim=True)
    tied = q >= top - 1e-12 * top.abs().clamp_min(1.0)
    return torch.where(tied, u, -1.0).argmax(-1)


class DGPQ:
    """Algorithm 1 for S seeds at once (one Q̂ and |A| GPs per seed)."""

    Config = DGPQConfig
    grows = True    # Q̂ keeps every pair step 6 gives it, pruning only those a new pair bounds
    COUNTERS = ("since_fit", "kernel_fits", "qhat_updates", "gp_adds")

    def __init__(self, cfg: DGPQConfig, seeds: Sequence[int], state_dim: int, num_actions: int,
                 kernel=None, device=None, state_box=None, scale=None):
        self.cfg = cfg.resolve(num_actions, state_box)
        self.scale = scale          # state_scale as (kept dimensions, their weights), or None; see features()
        self._features = []         # [(observation, features)], the last two
        self.S, self.A = len(seeds), num_actions
        self.qhat = LipschitzQ(self.S, num_actions, state_dim, cfg.lipschitz, cfg.v_max, cfg.metric,
                               capacity=cfg.qhat_capacity, device=device)
        kernel = kernel if kernel is not None else make_kernel(cfg.gp, state_dim, seeds, num_actions)
        self.gp = make_gp(cfg.gp, state_dim, (self.S, num_actions), kernel, device)
        self.trains_kernel = cfg.gp.kernel == "manifold"
        self.since_fit = torch.zeros(self.S, num_actions, dtype=torch.long, device=device)
        self.kernel_fits = torch.zeros(self.S, dtype=torch.long, device=device)
        self.rng = SeedStreams(seeds, stream=TIE_STREAM, device=device)
        self.qhat_updates = torch.zeros(self.S, dtype=torch.long, device=device)
        self.gp_adds = torch.zeros(self.S, dtype=torch.long, device=device)
        self._memo = (None, -1, None)  # (state tensor, Q̂ version, Q̂ values)
        self._seeds = torch.arange(self.S, device=device)

    # ------------------------------------------------------------ runner API
    @classmethod
    def resolve_config(cls, cfg: DGPQConfig, info) -> DGPQConfig:
        cls._scale(cfg, info)
        return cfg.resolve(info.num_actions("dgpq"), cls._state_box(cfg, info))

    @classmethod
    def make(cls, cfg: DGPQConfig, info, seeds: Sequence[int]) -> "DGPQ":
        """For the env described by ``info`` (``trl_dgpq.envs.base.EnvInfo``)."""
        return cls(cfg, seeds, cls._state_dim(cfg, info), info.num_actions("dgpq"), device=info.device,
                   state_box=cls._state_box(cfg, info), scale=cls._scale(cfg, info))

    @staticmethod
    def _scale(cfg: DGPQConfig, info):
        """state_scale for this env as (indices of the dimensions kept, their weights), or
        None when observations are used as they are."""
        if not cfg.state_scale:
            return None
        dim = info.observation_dim
        if len(cfg.state_scale) not in (1, dim):
            raise ValueError(f"state_scale needs 1 or {dim} weights for this env, got {len(cfg.state_scale)}")
        weights = list(cfg.state_scale) * (dim // len(cfg.state_scale))
        keep = [i for i, w in enumerate(weights) if w != 0]
        return (torch.tensor(keep, device=info.device),
                torch.tensor([weights[i] for i in keep], dtype=torch.float64, device=info.device))

    @classmethod
    def _state_dim(cls, cfg: DGPQConfig, info) -> int:
        scale = cls._scale(cfg, info)
        return info.observation_dim if scale is None else len(scale[0])

    @classmethod
    def _state_box(cls, cfg: DGPQConfig, info):
        if not (cfg.covering == "env" and (cfg.sigma_tol2 is None or cfg.eps1 is None)):
            return None
        low, high = info.state_box()
        scale = cls._scale(cfg, info)
        if scale is None:
            return low, high
        keep, w = scale[0].tolist(), scale[1].tolist()
        return [low[i] * wi for i, wi in zip(keep, w)], [high[i] * wi for i, wi in zip(keep, w)]

    @classmethod
    def memory_bytes(cls, cfg: DGPQConfig, info, num_seeds: int) -> int:
        """Storage at the start (GPs and Q̂ of every seed and action)."""
        A, dim = info.num_actions("dgpq"), cls._state_dim(cfg, info)
        return num_seeds * A * (cfg.gp.bytes_per_gp(dim) + 8 * cfg.qhat_capacity * (dim + 1))

    def features(self, obs: torch.Tensor) -> torch.Tensor:
        """The state Q̂ and the GPs see: the observation (float64) times ``state_scale``,
        zero-weight dimensions dropped."""
        if self.scale is None:
            return obs.to(torch.float64)
        # Cached on the observation tensor: the qhat_values memo is keyed on the state tensor,
        # and s_{t+1} of one step is s_t of the next.
        for o, f in self._features:
            if o is obs:
                return f
        keep, weights = self.scale
        f = obs.to(torch.float64)[..., keep] * weights
        self._features = [(obs, f)] + self._features[:1]
        return f

    def growth_bytes(self) -> int:
        """Bytes the next step's storage growth may allocate (Q̂ and an exact GP double when full;
        the sparse GP has a fixed budget)."""
        return self.qhat.growth_bytes() + getattr(self.gp, "growth_bytes", lambda: 0)()

    def act(self, td) -> torch.Tensor:
        return self.select_action(self.features(td.get("observation")))

    def exploit(self, td) -> torch.Tensor:
        """Evaluation: step 1 as in training (Q̂'s greedy action, ties by the tie stream)."""
        return self.act(td)

    def observe(self, td, active: Optional[torch.Tensor] = None) -> dict:
        nxt = td.get("next")
        return self.learn(self.features(td.get("observation")), td.get("action"),
                          learning_reward(td, self.cfg.gamma).reshape(self.S), self.features(nxt.get("observation")),
                          nxt.get("terminated").reshape(self.S), active)

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
    def select_action(self, s: torch.Tensor) -> torch.Tensor:
        """Greedy action on Q̂ with random tie-breaking. s (S, dim) -> (S,) long."""
        return argmax_random_ties(self.qhat_values(s.to(torch.float64)), self.rng.uniform(self.A))

    # Step 3
    def q_target(self, r: torch.Tensor, s_next: torch.Tensor, terminal: torch.Tensor) -> torch.Tensor:
        bootstrap = self.qhat_values(s_next).amax(-1)
        if self.cfg.slack == "once":  # take off the eps1 that step 6 put on Q̂(s'), so it does not add up
            bootstrap = bootstrap - self.cfg.eps1
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

    def learn(self, s, a, r, s_next, terminal, active: Optional[torch.Tensor] = None) -> dict:
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
        c = self.cfg
        due = (self.since_fit >= c.kernel_train_every) & (self.gp.size >= c.kernel_min_points)
        if due.any():
            fit(self.gp, due, steps=c.kernel_train_steps, lr=c.kernel_lr, min_points=c.kernel_min_points)
            self.since_fit[due] = 0
            self.kernel_fits += due.sum(-1)

    def episode_stats(self) -> dict:
        """Per-seed counters for the per-episode CSV, each (S,)."""
        stats = dict(qhat_size=self.qhat.size(), qhat_updates=self.qhat_updates,
                     gp_size=self.gp.size.sum(-1), gp_adds=self.gp_adds)
        if self.trains_kernel:
            stats["kernel_fits"] = self.kernel_fits
        return stats

    def state_dict(self) -> dict:
        """Q̂, the GPs (with their kernel), the tie stream and the counters."""
        return {"qhat": self.qhat.state_dict(), "gp": self.gp.state_dict(), "rng": self.rng.state_dict(),
                **{name: getattr(self, name).clone() for name in self.COUNTERS}}

    def load_state_dict(self, state: dict) -> None:
        self.qhat.load_state_dict(state["qhat"])
        self.gp.load_state_dict(state["gp"])
        self.rng.load_state_dict(state["rng"])
        for name in self.COUNTERS:
            getattr(self, name).copy_(state[name])
        self._memo = (None, -1, None)
