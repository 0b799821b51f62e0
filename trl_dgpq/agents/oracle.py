"""A scripted pusher for the block-pushing env (``oracle``): the reference line of
the push experiments and a proof that the task can be solved.

Per seed, from the observation alone: push the block along the axis on which it
is farthest from the goal. If the pusher is behind the block on that axis (on
the side away from the goal) and lined up with it, move toward the goal; behind
but not lined up, slide sideways onto the block's line; not behind, step clear
of the block sideways and then back past it. All seeds at once, with masks.
Non-learning: ``observe`` does nothing and it holds no state.
"""
from __future__ import annotations

from dataclasses import dataclass

import torch

from ..config import setting
from ..envs.push import BLOCK_HALF, PUSHER_HALF, PushEnv
from .base import ScriptedAgent

CONTACT = PUSHER_HALF + BLOCK_HALF  # centre distance at which pusher and block touch
# Action index of moving +1 / -1 along axis 0 (x) and axis 1 (y): E, W and N, S.
PLUS, MINUS = torch.tensor([2, 0]), torch.tensor([3, 1])


@dataclass
class OracleConfig:
    """The scripted pusher."""
    align_tol: float = setting(0.055, "lined up when the pusher's centre is within this of the block's line "
                                      "(at least half a move, or sliding onto the line can overshoot forever)")

    def check(self) -> "OracleConfig":
        if not (0 < self.align_tol < CONTACT):
            raise ValueError(f"align_tol must be in (0, {CONTACT}), got {self.align_tol}")
        return self


class OraclePusher(ScriptedAgent):
    Config = OracleConfig

    def __init__(self, cfg: OracleConfig, goal: torch.Tensor):
        self.cfg, self.goal = cfg, goal.to(torch.float64)

    @classmethod
    def resolve_config(cls, cfg, env):
        if not isinstance(env, PushEnv):
            raise ValueError("oracle is the scripted pusher of the block-pushing env: use --env push")
        return cfg.check()

    @classmethod
    def make(cls, cfg, env, seeds):
        cls.resolve_config(cfg, env)
        return cls(cfg, env.goal[:2].cpu())

    def act(self, td) -> torch.Tensor:
        obs = td.get("observation").to(torch.float64)
        pusher, block = obs[:, 0:2], obs[:, 3:5]
        to_goal = self.goal.to(obs.device) - block
        axis = to_goal.abs().argmax(-1)                                   # (S,) the axis to push along
        rows = torch.arange(len(obs), device=obs.device)
        sign = torch.where(to_goal[rows, axis] >= 0, 1.0, -1.0).to(obs.dtype)
        ahead = (pusher[rows, axis] - block[rows, axis]) * sign          # > 0: pusher on the goal's side
        side = pusher[rows, 1 - axis] - block[rows, 1 - axis]            # offset across the push axis
        touching_or_behind = ahead <= -CONTACT + 0.01
        well_behind = ahead <= -CONTACT - 0.01                           # can move across without a collision
        lined_up = side.abs() <= self.cfg.align_tol
        clear = side.abs() >= CONTACT + 0.02                             # can pass beside the block
        toward, back = torch.where(sign > 0, PLUS[axis], MINUS[axis]), torch.where(sign > 0, MINUS[axis], PLUS[axis])
        across_to_line = torch.where(side > 0, MINUS[1 - axis], PLUS[1 - axis])
        across_away = torch.where(side >= 0, PLUS[1 - axis], MINUS[1 - axis])
        action = torch.where(clear, back, across_away)
        action = torch.where(well_behind, across_to_line, action)
        return torch.where(touching_or_behind & lined_up, toward, action).to(obs.device)
