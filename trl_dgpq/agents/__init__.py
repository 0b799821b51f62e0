"""The agent registry. A new agent: one file with its class (see ``base.Agent``) and
``Config`` dataclass, one line in ``AGENTS``, one entry in ``trl_dgpq/presets.py``."""
from ..dgpq import DGPQ
from .base import Agent
from .ddpg import DDPG
from .dqn import DQN
from .oracle import OraclePusher
from .random import RandomAgent
from .schedule import ACOptimalPolicy, TWAPPolicy

AGENTS = {"dgpq": DGPQ, "random": RandomAgent, "ac-optimal": ACOptimalPolicy, "twap": TWAPPolicy, "ddpg": DDPG,
          "oracle": OraclePusher, "dqn": DQN}


def make_agent(name: str, cfg, env, seeds):
    if name not in AGENTS:
        raise ValueError(f"unknown agent {name!r}; choose from {sorted(AGENTS)}")
    return AGENTS[name].make(cfg, env, seeds)


__all__ = ["AGENTS", "Agent", "make_agent"]
