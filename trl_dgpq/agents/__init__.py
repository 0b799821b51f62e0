"""The agent registry. A new agent: one file with its class (see ``base.Agent``) and
``Config`` dataclass, one line in ``AGENTS``, one entry in ``trl_dgpq/presets.py``."""
from ..dgpq import DGPQ
from .base import Agent
from .random import RandomAgent

AGENTS = {"dgpq": DGPQ, "random": RandomAgent}


def make_agent(name: str, cfg, env, seeds):
    if name not in AGENTS:
        raise ValueError(f"unknown agent {name!r}; choose from {sorted(AGENTS)}")
    return AGENTS[name].make(cfg, env, seeds)


__all__ = ["AGENTS", "Agent", "make_agent"]
