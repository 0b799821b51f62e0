"""A uniformly random policy: the floor every learner must beat, and the smallest
example of an agent (no settings, no learning)."""
from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import torch

from ..rng import POLICY_STREAM, SeedStreams


@dataclass
class RandomConfig:
    """Uniformly random actions (no settings)."""


class RandomAgent:
    Config = RandomConfig

    def __init__(self, seeds: Sequence[int], num_actions: int, device=None):
        self.num_actions = num_actions
        self.rng = SeedStreams(seeds, stream=POLICY_STREAM, device=device)

    @classmethod
    def resolve_config(cls, cfg, info):
        info.num_actions("random")
        return cfg

    @classmethod
    def make(cls, cfg, info, seeds):
        return cls(seeds, info.num_actions("random"), device=info.device)

    @staticmethod
    def memory_bytes(cfg, info, num_seeds: int) -> int:
        return 0

    def act(self, td) -> torch.Tensor:
        return (self.rng.uniform(1)[:, 0] * self.num_actions).long()

    def observe(self, td, active=None) -> None:
        pass

    def episode_stats(self) -> dict:
        return {}

    def state_dict(self) -> dict:
        return {"rng": self.rng.state_dict()}

    def load_state_dict(self, state: dict) -> None:
        self.rng.load_state_dict(state["rng"])
