"""The agent registry. A general agent (one that runs on any env whose actions suit
it) is one file with its class (see ``base.Agent``) and ``Config`` dataclass, one
line in ``AGENTS``, and presets in the domains it supports (``envs/<domain>/presets.py``).
A domain's own agents (scripted baselines) are named by its ``Domain`` instead.
Nothing is imported until an agent is used."""
from __future__ import annotations

import importlib
from typing import Optional

AGENTS = {
    "dgpq": "trl_dgpq.dgpq:DGPQ",
    "random": "trl_dgpq.agents.random:RandomAgent",
    "ddpg": "trl_dgpq.agents.ddpg:DDPG",
    "td3": "trl_dgpq.agents.td3:TD3",
    "dqn": "trl_dgpq.agents.dqn:DQN",
    "constant": "trl_dgpq.agents.constant:ConstantAgent",
}


def baselines() -> dict:
    """{agent name: its ``Domain``} of every domain's own agents."""
    from trl_dgpq.envs import domains
    return {agent: d for d in domains() for agent in d.baseline_paths}


def agent_names() -> list:
    return [*AGENTS, *baselines()]


def check_agent_name(name) -> str:
    """``name`` if it names an agent (the setting's parser)."""
    if not isinstance(name, str) or name not in agent_names():
        raise ValueError(f"agent must be one of {agent_names()}, got {name!r}")
    return name


def agent_class(name: str, env: Optional[str] = None) -> type:
    """The class of agent ``name``; a domain's own agent only on that domain's envs."""
    if name in AGENTS:
        module, _, cls = AGENTS[name].partition(":")
        return getattr(importlib.import_module(module), cls)
    owner = baselines().get(name)
    if owner is None:
        check_agent_name(name)
    from trl_dgpq.envs import split_name
    if env is not None and split_name(env)[0] != owner.name:
        raise ValueError(f"{name} is a baseline of the {owner.name} domain: use --env {owner.examples()[0]}")
    return owner.baseline(name)


__all__ = ["AGENTS", "agent_class", "agent_names", "baselines", "check_agent_name"]
