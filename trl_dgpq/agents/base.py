"""What the runner asks of an agent.

An agent acts for S seeds at once and learns from the TensorDicts the env hands
the collector. Its settings are one dataclass (``Config``); it is built from
(config, env info, seeds) -- ``EnvInfo`` (``trl_dgpq.envs.base``): the env's specs,
the keys its TensorDicts hold and its actions' names, never its class -- and keeps
seeds independent: seed i alone behaves exactly as
seed i in any batch. A non-learning agent (a scripted policy) is an agent whose
``observe`` does nothing. An agent whose state grows without bound as it learns says so with a
class attribute ``grows = True`` (``memory_bytes`` is then where it starts; the runner's note on
checkpoint sizes reads it).
"""
from __future__ import annotations

from typing import Optional, Protocol, Sequence, runtime_checkable

import torch
from tensordict import TensorDictBase


@runtime_checkable
class Agent(Protocol):
    Config: type  # settings dataclass; its field defaults are the agent's defaults

    @classmethod
    def resolve_config(cls, cfg, info):
        """Validate ``cfg`` for the env of ``info`` (raise ValueError, one line) and fill derived values."""

    @classmethod
    def make(cls, cfg, info, seeds: Sequence[int]) -> "Agent":
        """The agent for ``seeds`` on the env of ``info`` (``batch_size=[len(seeds)]``)."""

    @staticmethod
    def memory_bytes(cfg, info, num_seeds: int) -> int:
        """Estimated storage, so that runs that cannot fit are refused before they start."""

    def act(self, td: TensorDictBase) -> torch.Tensor:
        """Actions for the observations in ``td``, one per seed."""

    def exploit(self, td: TensorDictBase) -> torch.Tensor:
        """(Optional; default ``act``.) Actions with exploration off, for evaluation: no
        epsilon, no action noise. Must not change what the agent has learned."""

    def observe(self, td: TensorDictBase, active: Optional[torch.Tensor]) -> object:
        """Learn from the transition ``td`` (with its "next" entries); ``active`` (S,) bool
        masks out seeds that have finished their episodes."""

    def episode_stats(self) -> dict:
        """Per-seed numbers for the episode's CSV row, each a tensor (S,)."""

    def state_dict(self) -> dict:
        """Everything needed to continue exactly (tensors, numbers, nested dicts)."""

    def load_state_dict(self, state: dict) -> None:
        ...


class ScriptedAgent:
    """Base of non-learning agents (scripted policies): nothing to learn, store or save."""

    @staticmethod
    def memory_bytes(cfg, info, num_seeds: int) -> int:
        return 0

    def observe(self, td, active=None) -> None:
        pass

    def episode_stats(self) -> dict:
        return {}

    def state_dict(self) -> dict:
        return {}

    def load_state_dict(self, state: dict) -> None:
        pass


def learning_reward(td: TensorDictBase, gamma: float) -> torch.Tensor:
    """The reward of a transition as a learner should learn from it: the env's, plus
    γΦ(s') − Φ(s) where the env provides a potential (key ``potential``; Φ of a terminal
    state is 0). Shaping by a potential (Ng, Harada & Russell 1999) keeps the optimal
    policies of every γ; the learner passes its own, since the telescoping needs it."""
    nxt = td.get("next")
    reward = nxt.get("reward")
    if "potential" not in td.keys():
        return reward
    phi_next = torch.where(nxt.get("terminated"), torch.zeros_like(reward), nxt.get("potential"))
    return reward + gamma * phi_next - td.get("potential")
