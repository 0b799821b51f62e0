"""DQN (Mnih et al. 2015) as Stable-Baselines3 runs it: a Q-network (TorchRL's ``MLP``,
ReLU), the Huber loss of TD(0) targets from a target network (as TorchRL's ``DQNLoss``,
tested equal), Adam (torch's defaults, eps 1e-8, as SB3's DQN) with the gradient norm
clipped at ``max_grad_norm``; epsilon-greedy with epsilon annealed linearly from
``eps_init`` to ``eps_end`` over ``exploration_steps`` env steps.

All seeds learn as one (``neural``: the Q-networks stacked over seeds, per-seed
losses, clipping, replay and random streams; why the loss is not ``DQNLoss`` itself).
The schedule is SB3's (``DQN._on_step``, ``OffPolicyAlgorithm.collect_rollouts`` and
``_sample_action``; tests/test_dqn.py transcribes it and checks ours against it). Per
env step t = 1, 2, ... of the active seeds:

- act: uniformly at random while fewer than ``learning_starts`` steps are taken (SB3's
  warm-up), else epsilon-greedily with epsilon after t - 1 steps;
- store the transition, count the step;
- every ``target_update_interval``-th step, copy the online network to the target
  (counted in env steps, before this step's updates: SB3 copies in the rollout and
  trains after it);
- every ``train_freq``-th step, once t > ``learning_starts``, make ``gradient_steps``
  updates on minibatches of ``batch_size`` drawn with replacement from what is stored
  (SB3's ``gradient_steps = -1`` is ``train_freq`` here).

Observations are the env's (the gym envs': raw for DQN's presets); a discrete action
spec is required (liquidation: ``action_levels`` > 0).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence, Tuple

import torch
from tensordict import TensorDict
from torch import nn
from torchrl.modules import MLP

from ..config import setting
from ..rng import SeedStreams, stream_id
from ..tuning import Choice, IntRange, LogUniform, OfBudget, Uniform
from .neural import (SeedAdam, SeedBatchedLearner, SeedStack, Target, build_per_seed, clip_grad_norm_per_seed,
                     seed_mean)


@dataclass
class DQNConfig:
    """DQN (defaults: rl-baselines3-zoo's tuned Acrobot-v1 settings; presets per env)."""
    gamma: float = setting(0.99, "discount gamma", within="[0, 1]")
    hidden: Tuple[int, ...] = setting((256, 256), "Q-network hidden widths (ReLU)", within="[1, inf)",
                                      length=(1, None))
    lr: float = setting(6.3e-4, "Adam learning rate", within="(0, inf)")
    buffer_size: int = setting(50_000, "replay buffer capacity (transitions per seed)", within="[1, inf)")
    batch_size: int = setting(128, "minibatch size", within="[1, inf)")
    learning_starts: int = setting(0, "env steps of random actions before learning (updates once more are taken)",
                                   within="[0, inf)")
    train_freq: int = setting(4, "update every this many env steps", within="[1, inf)")
    gradient_steps: int = setting(4, "updates each time", within="[1, inf)")
    target_update_interval: int = setting(250, "env steps between copies of the online network to the target",
                                          within="[1, inf)")
    eps_init: float = setting(1.0, "initial exploration epsilon", within="[0, 1]")
    eps_end: float = setting(0.1, "final exploration epsilon", within="[0, 1]")
    exploration_steps: int = setting(12_000, "env steps over which epsilon falls linearly to eps_end",
                                     within="[1, inf)")
    max_grad_norm: float = setting(10.0, "gradient norm clip (per seed)", within="(0, inf)")

    def cross_check(self) -> None:
        if self.buffer_size < self.batch_size:
            raise ValueError(f"need 1 <= batch_size <= buffer_size, got {self.batch_size} and {self.buffer_size}")
        if self.eps_end > self.eps_init:
            raise ValueError(f"need 0 <= eps_end <= eps_init <= 1, got {self.eps_end} and {self.eps_init}")


# What `trl-dgpq tune` searches (trl_dgpq/tuning.py); epsilon's decay as a fraction of a budget of env steps.
SEARCH_SPACE = {
    "lr": LogUniform(1e-4, 1e-2),
    "hidden": Choice(((64, 64), (128, 128), (256, 256))),
    "target_update_interval": IntRange(10, 1_000, log=True),
    "eps_end": Uniform(0.01, 0.2),
    "exploration_steps": OfBudget(0.05, 0.5, otherwise=IntRange(500, 20_000, log=True)),
    "batch_size": Choice((32, 64, 128, 256)),
    "buffer_size": Choice((10_000, 50_000, 100_000)),
    "train_freq": Choice((1, 4, 8, 16)),
    "gradient_steps": Choice((1, 2, 4, 8)),
}


class DQN(SeedBatchedLearner):
    """DQN for S seeds: one stacked Q-network, one loss, one optimiser."""

    Config = DQNConfig

    def __init__(self, cfg: DQNConfig, seeds: Sequence[int], obs_dim: int, n_actions: int):
        super().__init__(seeds, cfg.buffer_size)
        self.cfg, self.batch_size, self.n_actions = cfg, cfg.batch_size, n_actions
        qnet = SeedStack(build_per_seed(lambda: MLP(in_features=obs_dim, out_features=n_actions,
                                                    num_cells=list(cfg.hidden), activation_class=nn.ReLU),
                                        self.seeds))
        self.nets = nn.ModuleDict(dict(qnet=qnet, target=Target(qnet)))
        self.qnet, self.target = qnet, self.nets["target"]
        self.params = list(qnet.parameters())
        self.optimizers = [SeedAdam(qnet, lr=cfg.lr)]
        self.explore_rng = SeedStreams(self.seeds, stream_id("dqn.explore"))

    @property
    def eps(self) -> float:
        """Epsilon at the next action: linear from eps_init to eps_end over exploration_steps env steps."""
        cfg = self.cfg
        return cfg.eps_end + (cfg.eps_init - cfg.eps_end) * max(0.0, 1.0 - self.steps / cfg.exploration_steps)

    def greedy(self, obs: torch.Tensor) -> torch.Tensor:
        """argmax_a Q(obs, a) per seed: obs (S, obs_dim) -> (S,) long."""
        with torch.no_grad():
            return self.qnet(obs.to(torch.float32)).argmax(-1)

    def exploit(self, td) -> torch.Tensor:
        """epsilon = 0 (evaluation)."""
        return self.greedy(td.get("observation"))

    def act(self, td) -> torch.Tensor:
        u = self.explore_rng.uniform(2)                           # (S, 2): explore?, which action
        random = (u[:, 1] * self.n_actions).long()
        if self.steps < self.cfg.learning_starts:                 # SB3's warm-up: random actions only
            return random
        return torch.where(u[:, 0] < self.eps, random, self.greedy(td.get("observation")))

    def wants_update(self) -> int:
        cfg = self.cfg
        # SB3 trains after a rollout of train_freq steps once num_timesteps > learning_starts,
        # sampling with replacement from what is stored, however little
        ready = self.steps > cfg.learning_starts
        return cfg.gradient_steps if ready and self.steps % cfg.train_freq == 0 else 0

    def td_loss(self, batch: TensorDict) -> torch.Tensor:
        """Per element (S, B): Huber(Q(s, a) - (r + gamma (1 - terminated) max_a' Q_target(s', a')))."""
        nxt = batch["next"]
        q = self.qnet(batch["observation"]).gather(-1, batch["action"].unsqueeze(-1)).squeeze(-1)
        with torch.no_grad():
            q_next = self.target(nxt["observation"]).max(-1).values
            y = nxt["reward"].squeeze(-1) + self.cfg.gamma * (~nxt["terminated"].squeeze(-1)) * q_next
        return nn.functional.smooth_l1_loss(q, y, reduction="none")

    def update(self, batch: TensorDict) -> None:
        optim = self.optimizers[0]
        optim.zero_grad()
        seed_mean(self.td_loss(batch)).backward()
        clip_grad_norm_per_seed(self.params, self.cfg.max_grad_norm)
        optim.step()

    def before_updates(self) -> None:
        if self.steps % self.cfg.target_update_interval == 0:
            self.target.copy_()

    def state_dict(self) -> dict:
        return {**super().state_dict(), "explore_rng": self.explore_rng.state_dict()}

    def load_state_dict(self, state: dict) -> None:
        super().load_state_dict(state)
        self.explore_rng.load_state_dict(state["explore_rng"])

    @classmethod
    def resolve_config(cls, cfg: DQNConfig, info) -> DQNConfig:
        info.num_actions("dqn")
        return cfg

    @classmethod
    def make(cls, cfg: DQNConfig, info, seeds):
        return cls(cfg, seeds, info.observation_dim, info.num_actions("dqn"))

    @staticmethod
    def memory_bytes(cfg: DQNConfig, info, num_seeds: int) -> int:
        """The replay memory when full (observation, next observation, action, reward, flags)."""
        return num_seeds * cfg.buffer_size * (4 * (2 * info.observation_dim + 1) + 8 + 2)
