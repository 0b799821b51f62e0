"""The domains, batched over seeds (``batch_size=[S]``); installed as ``trl_dgpq.envs``.

A domain is one folder under ``envs/`` (``envs/domain.py`` says what goes in it) and
one line in ``DOMAINS`` below; nothing is imported until a domain is used. An env
name is a domain's name, or ``<domain>:<id>`` for a family (``gym:CartPole-v1``: any
gymnasium id with discrete actions).
"""
from __future__ import annotations

import importlib
from typing import Optional, Tuple

from .domain import Domain

DOMAINS = {
    "square": "trl_dgpq.envs.square",
    "liquidation": "trl_dgpq.envs.liquidation",
    "push": "trl_dgpq.envs.push",
    "gym": "trl_dgpq.envs.gym",
    "corridor": "trl_dgpq.envs.corridor",
    "f16": "trl_dgpq.envs.f16",
}


def split_name(name) -> Tuple[str, Optional[str]]:
    """"gym:CartPole-v1" -> ("gym", "CartPole-v1"); "square" -> ("square", None)."""
    if not isinstance(name, str):
        raise ValueError(f"env must be text, got {name!r}")
    head, sep, env_id = name.partition(":")
    return head, (env_id if sep else None)


def domains() -> list:
    """Every registered ``Domain`` (importing each one's light ``__init__``)."""
    return [importlib.import_module(path).DOMAIN for path in DOMAINS.values()]


def domain(name: str) -> Domain:
    """The domain of env name ``name``; ValueError (one line) for an unknown one."""
    head, env_id = split_name(name)
    if head not in DOMAINS:
        examples = [e for d in domains() for e in d.examples()]
        raise ValueError(f"unknown env {name!r}; choose from {', '.join(examples)} (gym:ID: any gymnasium id "
                         "with discrete actions)")
    found = importlib.import_module(DOMAINS[head]).DOMAIN
    found.check_id(env_id)
    return found


def env_class(name: str) -> type:
    """The env class of ``name`` (refused in one line if the suite cannot run it)."""
    return domain(name).env_class(split_name(name)[1])


def check_env_name(name) -> str:
    """``name`` if it names an env the suite can run (the setting's parser)."""
    env_class(name)
    return name


def env_configs() -> list:
    """Every domain's env config class (for the command line's flags)."""
    return [d.config_class() for d in domains()]


def model_knowledge(config: dict) -> list:
    """What of its env's model the run of ``config`` uses (``Domain.model_knowledge``): a reward,
    potential, state or agent built from the model is a documented variant, never model-free."""
    return domain(config["run"]["env"]).model_knowledge(config)


def make_env(name: str, cfg, seeds, device="cpu"):
    return env_class(name)(seeds, cfg, device=device)


__all__ = ["DOMAINS", "Domain", "domain", "domains", "split_name", "env_class", "check_env_name", "env_configs",
           "make_env", "model_knowledge"]
