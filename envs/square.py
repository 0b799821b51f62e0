"""The 2-D square of GWH14's first experiment (seed report 4.1), batched over seeds.

State in [0, 1]^2, start (0, 0). Actions 0..3 move 0.1 north / south / east / west,
plus uniform noise in [-0.01, 0.01] on the moved axis (from the seed's own stream);
the result is clipped to the square. Reaching Euclidean distance <= 0.15 from
(1, 1) terminates; the step cap (200) truncates. Rewards:
  "shaped": r = 2 - |(1, 1) - s'|_2
  "paper":  r = -1 per step, 0 on reaching the goal
"""
from __future__ import annotations

import torch
from torchrl.data import Bounded, Categorical, Composite, Unbounded

from .base import SeedBatchedEnv

# name -> env settings and DGPQ settings (SPEC 3.1). V_max of "shaped" is R_max / (1 - gamma).
PRESETS = {
    "shaped": dict(env=dict(reward="shaped"),
                   agent=dict(gamma=0.01, lipschitz=1.0, v_max=2.0 / 0.99, lengthscale=0.05, outputscale=1.0,
                              noise_var=0.1, sigma_tol2=0.1, eps1=0.001, metric="l1")),
    "report": dict(env=dict(reward="shaped"),
                   agent=dict(gamma=0.01, lipschitz=9.0, v_max=400.0, lengthscale=0.05, outputscale=1.0,
                              noise_var=0.1, sigma_tol2=None, eps1=None, eps=1.0, delta=0.96, r_max=2.0,
                              metric="l1")),
    "paper": dict(env=dict(reward="paper"),
                  agent=dict(gamma=1.0, lipschitz=9.0, v_max=0.0, lengthscale=0.05, outputscale=0.5,
                             noise_var=0.1, sigma_tol2=0.1, eps1=0.001, metric="l1")),
}

MOVES = ((0.0, 1.0), (0.0, -1.0), (1.0, 0.0), (-1.0, 0.0))  # N, S, E, W
REWARDS = ("shaped", "paper")


class SquareEnv(SeedBatchedEnv):
    """TorchRL env, ``batch_size=[len(seeds)]``; observations are float64 ``(S, 2)``."""

    def __init__(self, seeds=(0,), reward: str = "shaped", max_steps: int = 200, step_size: float = 0.1,
                 noise: float = 0.01, goal=(1.0, 1.0), goal_radius: float = 0.15, device="cpu"):
        if reward not in REWARDS:
            raise ValueError(f"reward must be one of {REWARDS}, got {reward!r}")
        if not (step_size > 0 and noise >= 0 and goal_radius > 0):
            raise ValueError("need step_size > 0, noise >= 0 and goal_radius > 0")
        self.reward_type, self.step_size, self.noise, self.goal_radius = reward, step_size, noise, goal_radius
        super().__init__(seeds, max_steps, device)
        self.goal = torch.tensor(goal, dtype=torch.float64, device=self.device)
        self.moves = torch.tensor(MOVES, dtype=torch.float64, device=self.device)
        self.pos = torch.zeros(self.num_seeds, 2, dtype=torch.float64, device=self.device)

    def _make_specs(self) -> None:
        S = self.num_seeds
        self.observation_spec = Composite(
            observation=Bounded(0.0, 1.0, shape=(S, 2), dtype=torch.float64, device=self.device),
            shape=(S,), device=self.device)
        self.action_spec = Categorical(len(MOVES), shape=(S,), device=self.device)
        self.reward_spec = Unbounded(shape=(S, 1), dtype=torch.float64, device=self.device)

    def _initial(self, mask):
        self.pos[mask] = 0.0
        return self._td(observation=self.pos.clone())

    def _transition(self, action):
        jitter = (2.0 * self.rng.uniform(1) - 1.0) * self.noise            # (S, 1), the seed's own stream
        self.pos = (self.pos + self.moves[action] * (self.step_size + jitter)).clamp(0.0, 1.0)
        dist = torch.linalg.vector_norm(self.goal - self.pos, dim=-1)
        terminated = dist <= self.goal_radius
        if self.reward_type == "shaped":
            reward = 2.0 - dist
        else:
            reward = torch.where(terminated, 0.0, -1.0).to(torch.float64)
        return self._td(observation=self.pos.clone()), reward, terminated
