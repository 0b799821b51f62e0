"""Scripted liquidation schedules, the yardsticks of the liquidation env: the
Almgren-Chriss optimum (``ac-optimal``) and TWAP (``twap``, equal trades).

Each reads the trades left from the step's TensorDict (``trades_left``) and sells
the schedule's fraction of the shares still held, so rounding to whole shares never
accumulates. Non-learning agents: ``observe`` does nothing and they hold no state.
"""
from __future__ import annotations

from dataclasses import dataclass

import torch

from trl_dgpq.agents.base import ScriptedAgent

from .almgren_chriss import ACModel


@dataclass
class ScheduleConfig:
    """A fixed liquidation schedule (no settings)."""


class SchedulePolicy(ScriptedAgent):
    """Sells ``fractions[k]`` of the remaining shares at trade k + 1 (a tensor (N,))."""

    Config = ScheduleConfig
    name = "schedule"

    def __init__(self, fractions: torch.Tensor, trades: int):
        self.fractions, self.trades = fractions.to(torch.float64), trades

    @classmethod
    def resolve_config(cls, cfg, info):
        if info.config.action_levels:
            raise ValueError(f"{cls.name} sells exact fractions: set action_levels=0 (continuous actions)")
        return cfg

    @classmethod
    def make(cls, cfg, info, seeds):
        return cls(cls.schedule(ACModel.from_config(info.config)), info.config.trades)

    @staticmethod
    def schedule(model: ACModel) -> torch.Tensor:
        raise NotImplementedError

    def act(self, td) -> torch.Tensor:
        k = (self.trades - td.get("trades_left")).long().clamp(0, self.trades - 1)  # trades done
        return self.fractions[k][:, None]


class ACOptimalPolicy(SchedulePolicy):
    """The Almgren-Chriss optimal schedule x_j = sinh(kappa (T - t_j)) / sinh(kappa T) X."""
    name = "ac-optimal"

    @staticmethod
    def schedule(model: ACModel) -> torch.Tensor:
        return model.sell_fractions()


class TWAPPolicy(SchedulePolicy):
    """Time-weighted average price: X / N shares per trade (1 / (N - k + 1) of the rest)."""
    name = "twap"

    @staticmethod
    def schedule(model: ACModel) -> torch.Tensor:
        return 1.0 / torch.arange(model.trades, 0, -1, dtype=torch.float64)
