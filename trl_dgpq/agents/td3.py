"""TD3 (Fujimoto, van Hoof & Meger 2018): DDPG with the three corrections that made it
the standard deterministic-policy baseline -- twin critics whose smaller target value is
the TD target (against DDPG's overestimation), target policy smoothing (clipped Gaussian
noise on the target actor's action), and a delayed actor (one actor step and one soft
target update per ``policy_delay`` critic steps). Exploration: Gaussian noise on the
actor's action, uniform random actions for the first ``learning_starts`` steps.

Why TD3 rather than SAC on liquidation (issue 27): it is DDPG's direct successor, so the
comparison with the course's DDPG isolates what those three corrections buy on the same
deterministic actor and the same replay; SAC would change the policy class as well
(stochastic, with an entropy temperature to tune). Defaults are the TD3 paper's (its
author's reference code: (256, 256) networks, learning rates 3e-4, tau 0.005, batch 256,
exploration 0.1, policy noise 0.2 clipped at 0.5, delay 2), noises in units of half the
action box's width (the paper's max_action).

All seeds learn as one (``neural``: stacked networks, per-seed losses, replay and random
streams). The losses are TorchRL's ``TD3Loss``'s (tested equal on one seed) written on the
stacked tensors, for the reason ``neural`` gives for DDPG.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence, Tuple

import torch
from tensordict import TensorDict
from torch import nn
from torchrl.data import Bounded
from torchrl.modules import MLP

from ..config import setting
from ..tuning import LogUniform, Uniform
from ..rng import SeedStreams, stream_id
from .ddpg import Actor
from .neural import SeedAdam, SeedBatchedLearner, SeedStack, Target, build_per_seed, seed_mean


@dataclass
class TD3Config:
    """TD3 (defaults: the TD3 paper's)."""
    gamma: float = setting(0.99, "discount gamma", within="[0, 1]")
    actor_hidden: Tuple[int, ...] = setting((256, 256), "actor hidden widths (ReLU), then tanh onto the action box",
                                            within="[1, inf)", length=(1, None))
    critic_hidden: Tuple[int, ...] = setting((256, 256), "each critic's hidden widths (ReLU) on (state, action)",
                                             within="[1, inf)", length=(1, None))
    actor_lr: float = setting(3e-4, "actor Adam learning rate", within="(0, inf)")
    critic_lr: float = setting(3e-4, "critics' Adam learning rate", within="(0, inf)")
    target_update: float = setting(5e-3, "soft target update weight tau", within="(0, 1]")
    buffer_size: int = setting(100_000, "replay buffer capacity (transitions per seed)", within="[1, inf)")
    batch_size: int = setting(256, "minibatch size", within="[1, inf)")
    learning_starts: int = setting(1_000, "env steps of uniform random actions before learning", within="[0, inf)")
    expl_noise: float = setting(0.1, "exploration noise s.d. (half action-box widths)", within="[0, inf)")
    policy_noise: float = setting(0.2, "target policy smoothing noise s.d. (half action-box widths)",
                                  within="[0, inf)")
    noise_clip: float = setting(0.5, "target policy noise clipped to +-this (half action-box widths)",
                                within="[0, inf)")
    policy_delay: int = setting(2, "critic steps per actor step and target update", within="[1, inf)")

    def cross_check(self) -> None:
        if self.buffer_size < self.batch_size:
            raise ValueError(f"need 1 <= batch_size <= buffer_size, got {self.batch_size} and {self.buffer_size}")


# What a study searches (trl_dgpq/tuning.py), DDPG's ranges for the shared settings so the
# two are tuned alike, plus TD3's own noises.
SEARCH_SPACE = {
    "actor_lr": LogUniform(1e-5, 1e-3),
    "critic_lr": LogUniform(1e-4, 1e-2),
    "target_update": LogUniform(1e-3, 0.1),
    "expl_noise": Uniform(0.02, 0.5),
    "policy_noise": Uniform(0.05, 0.5),
}


class TwinCritic(nn.Module):
    """Two critics Q1, Q2 on the concatenated (state, action): (..., 2)."""

    def __init__(self, obs_dim: int, act_dim: int, hidden: Tuple[int, ...]):
        super().__init__()
        make = lambda: MLP(in_features=obs_dim + act_dim, out_features=1, num_cells=list(hidden),  # noqa: E731
                           activation_class=nn.ReLU)
        self.q1, self.q2 = make(), make()

    def forward(self, observation, action):
        x = torch.cat([observation, action], -1)
        return torch.cat([self.q1(x), self.q2(x)], -1)


class TD3(SeedBatchedLearner):
    """TD3 for S seeds: a stacked actor, stacked twin critics, their targets, two optimisers."""

    Config = TD3Config

    def __init__(self, cfg: TD3Config, seeds: Sequence[int], obs_dim: int, box: Bounded):
        super().__init__(seeds, cfg.buffer_size)
        self.cfg, self.batch_size = cfg, cfg.batch_size
        self.low, self.high = box.space.low[0].float(), box.space.high[0].float()
        self.scale = (self.high - self.low) / 2  # the paper's max_action: noises are in its units
        act_dim = self.low.numel()

        def actor_and_critics():
            return nn.ModuleList([MLP(in_features=obs_dim, out_features=act_dim, num_cells=list(cfg.actor_hidden),
                                      activation_class=nn.ReLU), TwinCritic(obs_dim, act_dim, cfg.critic_hidden)])
        pairs = build_per_seed(actor_and_critics, self.seeds)
        actor = Actor(SeedStack([p[0] for p in pairs]), self.low, self.high)
        critic = SeedStack([p[1] for p in pairs])
        self.nets = nn.ModuleDict(dict(actor=actor, critic=critic, target_actor=Target(actor),
                                       target_critic=Target(critic)))
        self.actor, self.critic = actor, critic
        self.actor_optim = SeedAdam(actor.mlp, lr=cfg.actor_lr)
        self.critic_params = list(critic.parameters())
        self.critic_optim = SeedAdam(critic, lr=cfg.critic_lr)
        self.optimizers = [self.actor_optim, self.critic_optim]
        self.explore_rng = SeedStreams(self.seeds, stream_id("td3.explore"))
        self.smooth_rng = SeedStreams(self.seeds, stream_id("td3.smoothing"))
        self.critic_steps = 0  # of every active seed (seeds learn in lock-step)

    def exploit(self, td) -> torch.Tensor:
        """The actor's action, no noise (evaluation), float64 (S, act_dim)."""
        with torch.no_grad():
            return self.actor(td.get("observation").to(torch.float32)).to(torch.float64)

    def act(self, td) -> torch.Tensor:
        """Uniform in the box during the warm-up, then the actor's action plus Gaussian noise,
        clipped to the box; float64 (S, act_dim)."""
        act_dim = self.low.numel()
        if self.steps < self.cfg.learning_starts:
            u = self.explore_rng.uniform(act_dim).to(torch.float32)
            return (self.low + (self.high - self.low) * u).to(torch.float64)
        noise = self.explore_rng.normal(act_dim).to(torch.float32) * self.cfg.expl_noise * self.scale
        with torch.no_grad():
            action = self.actor(td.get("observation").to(torch.float32))
        return (action + noise).clamp(self.low, self.high).to(torch.float64)

    def wants_update(self) -> int:
        return int(self.steps > self.cfg.learning_starts)

    def target_action(self, next_obs: torch.Tensor, noise: torch.Tensor) -> torch.Tensor:
        """The target actor's action at s' with smoothing ``noise`` (S, B, act_dim, standard
        normal) scaled, clipped to +-noise_clip, added, and the sum clipped to the box."""
        cfg = self.cfg
        eps = (noise * cfg.policy_noise * self.scale).clamp(-cfg.noise_clip * self.scale, cfg.noise_clip * self.scale)
        return (self.nets["target_actor"](next_obs) + eps).clamp(self.low, self.high)

    def value_loss(self, batch: TensorDict, noise: torch.Tensor) -> torch.Tensor:
        """Per element (S, B): (Q1(s, a) - y)^2 + (Q2(s, a) - y)^2 with
        y = r + gamma (1 - terminated) min(Q1', Q2')(s', target_action(s'))."""
        nxt = batch["next"]
        with torch.no_grad():
            q_next = self.nets["target_critic"](nxt["observation"], self.target_action(nxt["observation"], noise))
            y = nxt["reward"] + self.cfg.gamma * (~nxt["terminated"]) * q_next.min(-1, keepdim=True).values
        return (self.critic(batch["observation"], batch["action"]) - y).pow(2).sum(-1)

    def actor_loss(self, batch: TensorDict) -> torch.Tensor:
        """Per element (S, B): -Q1(s, actor(s)), the critics held fixed."""
        obs = batch["observation"]
        for p in self.critic_params:
            p.requires_grad_(False)
        try:
            return -self.critic(obs, self.actor(obs))[..., 0]
        finally:
            for p in self.critic_params:
                p.requires_grad_(True)

    def update(self, batch: TensorDict) -> None:
        S, B = batch.shape
        noise = self.of_updating(self.smooth_rng.normal(B, self.low.numel())).to(torch.float32)  # every seed draws
        self.critic_optim.zero_grad()
        seed_mean(self.value_loss(batch, noise)).backward()
        self.critic_optim.step()
        self.critic_steps += 1
        if self.critic_steps % self.cfg.policy_delay == 0:
            self.actor_optim.zero_grad()
            seed_mean(self.actor_loss(batch)).backward()
            self.actor_optim.step()
            for name in ("actor", "critic"):
                self.nets[f"target_{name}"].soft_update_(self.cfg.target_update)

    def state_dict(self) -> dict:
        return {**super().state_dict(), "explore_rng": self.explore_rng.state_dict(),
                "smooth_rng": self.smooth_rng.state_dict(), "critic_steps": self.critic_steps}

    def load_state_dict(self, state: dict) -> None:
        super().load_state_dict(state)
        self.explore_rng.load_state_dict(state["explore_rng"])
        self.smooth_rng.load_state_dict(state["smooth_rng"])
        self.critic_steps = int(state["critic_steps"])

    @classmethod
    def resolve_config(cls, cfg: TD3Config, info) -> TD3Config:
        info.action_box("td3")
        return cfg

    @classmethod
    def make(cls, cfg: TD3Config, info, seeds):
        return cls(cfg, seeds, info.observation_dim, info.action_box("td3"))

    @staticmethod
    def memory_bytes(cfg: TD3Config, info, num_seeds: int) -> int:
        """The replay memory when full (observation, next observation, action, reward, flags)."""
        dim, act = info.observation_dim, int(info.action_box("td3").shape[-1])
        return num_seeds * cfg.buffer_size * (4 * (2 * dim + act + 1) + 2)
