"""The same action every step: a yardstick where one action is optimal (the corridor's
"right"), a floor where none is, and the worked example of an agent (docs/architecture.md, "Adding an
agent"). No learning and no state."""
from __future__ import annotations

from dataclasses import dataclass

import torch

from .base import ScriptedAgent
from ..config import setting


@dataclass
class ConstantConfig:
    """One action, always."""
    action: str = setting("0", "the action: its index, or its name where the env names its actions")


class ConstantAgent(ScriptedAgent):
    Config = ConstantConfig

    def __init__(self, index: int, num_seeds: int, device=None):
        self.action = torch.full((num_seeds,), index, dtype=torch.long, device=device)

    @staticmethod
    def index(cfg: ConstantConfig, info) -> int:
        n = info.num_actions("constant")
        index = int(cfg.action) if cfg.action.isdigit() else info.action_index(cfg.action)
        if index >= n:
            raise ValueError(f"action {index} is not among this env's {n} actions")
        return index

    @classmethod
    def resolve_config(cls, cfg: ConstantConfig, info) -> ConstantConfig:
        cls.index(cfg, info)
        return cfg

    @classmethod
    def make(cls, cfg: ConstantConfig, info, seeds):
        return cls(cls.index(cfg, info), len(seeds), info.device)

    def act(self, td) -> torch.Tensor:
        return self.action
