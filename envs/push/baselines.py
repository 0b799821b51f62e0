"""A scripted pusher for the block-pushing env (``oracle``): the reference line of
the push experiments and a proof that the task can be solved.

Per seed, from the pusher's and the block's positions alone (``pusher``, ``block``,
read by key; moves found by their action names): push the block along x until it is
within goal_radius / sqrt(2) of the goal's x, then along y (a fixed order: choosing
the farther axis each step thrashes on diagonals, each switch costing a detour). If
the pusher is behind the block on that axis (on the side away from the goal) and
lined up with it, move toward the goal; behind but not lined up, slide sideways onto
the block's line; not behind, step clear of the block sideways and then back past
it. All seeds at once, with masks.
Non-learning: ``observe`` does nothing and it holds no state.
"""
from __future__ import annotations

from dataclasses import dataclass

import torch

from trl_dgpq.agents.base import ScriptedAgent
from trl_dgpq.config import setting

from .env import BLOCK_HALF, PUSHER_HALF

CONTACT = PUSHER_HALF + BLOCK_HALF  # centre distance at which pusher and block touch


@dataclass
class OracleConfig:
    """The scripted pusher."""
    align_tol: float = setting(0.055, "lined up when the pusher's centre is within this of the block's line "
                                      "(at least half a move, or sliding onto the line can overshoot forever)",
                               within=f"(0, {CONTACT})")


class OraclePusher(ScriptedAgent):
    Config = OracleConfig

    def __init__(self, cfg: OracleConfig, goal: torch.Tensor, tol: float, plus: torch.Tensor, minus: torch.Tensor):
        self.cfg, self.goal, self.tol = cfg, goal.to(torch.float64), tol
        self.plus, self.minus = plus, minus  # action moving +1 / -1 along axis 0 (x) and axis 1 (y)

    @classmethod
    def resolve_config(cls, cfg, info):
        push = info.config
        move = push.step_size
        # A push moves the block about a move: to land within tol of the goal on each axis,
        # 2 tol must span a move; to slide onto the block's line, 2 align_tol must too (noise
        # can only help it out of a cycle).
        if push.goal_radius / 2 ** 0.5 < move / 2:
            raise ValueError(f"oracle pushes in moves of {move:g}: it needs goal_radius >= {move / 2 ** 0.5:.3g} "
                             f"(step_size / sqrt 2), got {push.goal_radius}")
        if 2 * cfg.align_tol < move:
            raise ValueError(f"oracle lines up in moves of {move:g}: it needs align_tol >= {move / 2:g}, got "
                             f"{cfg.align_tol} (and align_tol < {CONTACT}, so step_size <= {2 * CONTACT:g})")
        return cfg

    @classmethod
    def make(cls, cfg, info, seeds):
        index = lambda *names: torch.tensor([info.action_index(n) for n in names])  # noqa: E731
        return cls(cfg, torch.tensor(info.config.goal, dtype=torch.float64), info.config.goal_radius / 2 ** 0.5,
                   plus=index("east", "north"), minus=index("west", "south"))

    def act(self, td) -> torch.Tensor:
        pusher, block = td.get("pusher")[:, :2].to(torch.float64), td.get("block")[:, :2].to(torch.float64)
        to_goal = self.goal.to(block.device) - block
        axis = (to_goal[:, 0].abs() <= self.tol).long()                   # (S,) x first, then y
        rows = torch.arange(len(block), device=block.device)
        sign = torch.where(to_goal[rows, axis] >= 0, 1.0, -1.0).to(block.dtype)
        ahead = (pusher[rows, axis] - block[rows, axis]) * sign          # > 0: pusher on the goal's side
        side = pusher[rows, 1 - axis] - block[rows, 1 - axis]            # offset across the push axis
        touching_or_behind = ahead <= -CONTACT + 0.01
        well_behind = ahead <= -CONTACT - 0.01                           # can move across without a collision
        lined_up = side.abs() <= self.cfg.align_tol
        clear = side.abs() >= CONTACT + 0.02                             # can pass beside the block
        plus, minus = self.plus.to(block.device), self.minus.to(block.device)
        toward, back = torch.where(sign > 0, plus[axis], minus[axis]), torch.where(sign > 0, minus[axis], plus[axis])
        across_to_line = torch.where(side > 0, minus[1 - axis], plus[1 - axis])
        across_away = torch.where(side >= 0, plus[1 - axis], minus[1 - axis])
        action = torch.where(clear, back, across_away)
        action = torch.where(well_behind, across_to_line, action)
        return torch.where(touching_or_behind & lined_up, toward, action)
