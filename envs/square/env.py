"""The 2-D square of GWH14's first experiment (seed report 4.1), batched over seeds.

State in [0, 1]^2, start (0, 0). Actions 0..3 move ``step_size`` north / south /
east / west, plus uniform noise in [-noise, noise] on the moved axis (from the
seed's own stream); the result is clipped to the square. Reaching Euclidean
distance <= ``goal_radius`` from the goal terminates; the step cap truncates.
Rewards:
  "shaped": r = 2 - |goal - s'|_2
  "paper":  r = -1 per step, 0 on reaching the goal
plus, with ``reward_noise`` > 0, Gaussian noise of that standard deviation on every
reward (its own stream, so the moves are the same with and without it): the
"noisy" presets, where a GP must average several samples before Q̂ moves.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Tuple

import torch
from torchrl.data import Bounded, Categorical, Composite, Unbounded

from trl_dgpq.config import setting

from ..base import SeedBatchedEnv

MOVES = ((0.0, 1.0), (0.0, -1.0), (1.0, 0.0), (-1.0, 0.0))  # N, S, E, W
REWARD_NOISE_STREAM = 7  # the reward noise's stream id (trl_dgpq.rng: ids 1-7 are taken)
REWARDS = ("shaped", "paper")


@dataclass
class SquareConfig:
    """The 2-D square (SPEC 3.1)."""
    reward: str = setting("shaped", "shaped: 2 - |goal - s|_2 per step; paper: -1 per step, 0 at the goal",
                          choices=REWARDS)
    max_steps: int = setting(200, "step cap per episode (truncation, not termination)", within="[1, inf)")
    step_size: float = setting(0.1, "length of a move", within="(0, inf)")
    noise: float = setting(0.01, "uniform noise on the moved axis, in [-noise, noise]", within="[0, inf)")
    goal: Tuple[float, ...] = setting((1.0, 1.0), "goal position, e.g. 1,1", within="[0, 1]", length=2)
    goal_radius: float = setting(0.15, "episode ends (terminated) within this Euclidean distance of the goal",
                                 within="(0, inf)")
    reward_noise: float = setting(0.0, "standard deviation of Gaussian noise added to every reward",
                                  within="[0, inf)")


class SquareEnv(SeedBatchedEnv):
    """TorchRL env, ``batch_size=[len(seeds)]``; observations are float64 ``(S, 2)``."""

    Config = SquareConfig
    action_names = ("north", "south", "east", "west")
    _state_names = ("pos",)
    _streams = (("reward_rng", REWARD_NOISE_STREAM),)

    def __init__(self, seeds=(0,), cfg: SquareConfig | None = None, device="cpu", **overrides):
        super().__init__(seeds, cfg, device, **overrides)
        self.goal = torch.tensor(self.cfg.goal, dtype=torch.float64, device=self.device)
        self.moves = torch.tensor(MOVES, dtype=torch.float64, device=self.device)
        self.pos = torch.zeros(self.num_seeds, 2, dtype=torch.float64, device=self.device)

    @classmethod
    def _specs(cls, cfg, S, device):
        observation = Composite(observation=Bounded(0.0, 1.0, shape=(S, 2), dtype=torch.float64, device=device),
                                shape=(S,), device=device)
        return (observation, Categorical(len(MOVES), shape=(S,), device=device),
                Unbounded(shape=(S, 1), dtype=torch.float64, device=device))

    def _initial(self, mask):
        self.pos[mask] = 0.0
        return self._td(observation=self.pos.clone())

    def _transition(self, action):
        cfg = self.cfg
        jitter = (2.0 * self.rng.uniform(1) - 1.0) * cfg.noise            # (S, 1), the seed's own stream
        self.pos.copy_((self.pos + self.moves[action] * (cfg.step_size + jitter)).clamp(0.0, 1.0))
        dist = torch.linalg.vector_norm(self.goal - self.pos, dim=-1)
        terminated = dist <= cfg.goal_radius
        if cfg.reward == "shaped":
            reward = 2.0 - dist
        else:
            reward = torch.where(terminated, 0.0, -1.0).to(torch.float64)
        if cfg.reward_noise:
            reward = reward + cfg.reward_noise * self.reward_rng.normal(1)[:, 0]
        return self._td(observation=self.pos.clone()), reward, terminated


Env = SquareEnv
