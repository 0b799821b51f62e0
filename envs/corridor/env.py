"""A corridor of ``length`` cells, batched over seeds: start in cell 0, the goal is the
last cell. Actions 0 ("left") and 1 ("right") move one cell; with probability ``slip``
(the seed's own stream) the move goes the other way; the walls stop it. Reward -1 per
step, 0 on reaching the goal (terminated); the step cap truncates. Observation: the
cell / (length - 1), in [0, 1]. Always "right" is optimal: (length - 1) / (1 - 2 slip)
steps expected.
"""
from __future__ import annotations

from dataclasses import dataclass

import torch
from torchrl.data import Bounded, Categorical, Composite, Unbounded

from trl_dgpq.config import setting

from ..base import SeedBatchedEnv


@dataclass
class CorridorConfig:
    """The 1-D corridor."""
    length: int = setting(10, "cells, the goal the last", within="[2, inf)")
    slip: float = setting(0.1, "probability that a move goes the other way", within="[0, 0.5)")
    max_steps: int = setting(50, "step cap per episode (truncation, not termination)", within="[1, inf)")


class CorridorEnv(SeedBatchedEnv):
    """TorchRL env, ``batch_size=[len(seeds)]``; observations float64 ``(S, 1)``."""

    Config = CorridorConfig
    action_names = ("left", "right")
    _state_names = ("cell",)

    def __init__(self, seeds=(0,), cfg: CorridorConfig | None = None, device="cpu", **overrides):
        super().__init__(seeds, cfg, device, **overrides)
        self.cell = torch.zeros(self.num_seeds, dtype=torch.long, device=self.device)

    @classmethod
    def _specs(cls, cfg, S, device):
        observation = Composite(observation=Bounded(0.0, 1.0, shape=(S, 1), dtype=torch.float64, device=device),
                                shape=(S,), device=device)
        return (observation, Categorical(2, shape=(S,), device=device),
                Unbounded(shape=(S, 1), dtype=torch.float64, device=device))

    def _observe(self):
        return self._td(observation=(self.cell.to(torch.float64) / (self.cfg.length - 1))[:, None])

    def _initial(self, mask):
        self.cell[mask] = 0
        return self._observe()

    def _transition(self, action):
        slipped = self.rng.uniform(1)[:, 0] < self.cfg.slip            # the seed's own stream
        step = torch.where((action == 1) ^ slipped, 1, -1)
        self.cell.copy_((self.cell + step).clamp(0, self.cfg.length - 1))
        terminated = self.cell == self.cfg.length - 1
        reward = torch.where(terminated, 0.0, -1.0).to(torch.float64)
        return self._observe(), reward, terminated


Env = CorridorEnv
