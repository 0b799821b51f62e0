"""Named settings per (env, agent): overrides of the config dataclasses' defaults, and
nothing else. Each domain keeps its own in ``envs/<domain>/presets.py`` (``PRESETS``
by agent, and ``DEFAULT``, the default preset's name); this module holds the
building blocks several domains share and the lookup.

Keys are setting names as on the command line (``noise_var``, or dotted paths).
"""
from __future__ import annotations

# DQN on the suite's own envs (not tuned; README "DGPQ against DQN"): rl-baselines3-zoo's
# CartPole-scale settings shrunk to these small tasks -- a (64, 64) network, one update per
# step from the 256th, a target copy every 100 steps, epsilon down to 0.05 over 2,000 steps.
SMALL_DQN = dict(hidden=(64, 64), lr=1e-3, batch_size=64, buffer_size=10_000, learning_starts=256, train_freq=1,
                 gradient_steps=1, target_update_interval=100, exploration_steps=2_000, eps_end=0.05)


def rbf_and_manifold(name: str, **agent) -> dict:
    """DGPQ presets ``name`` (RBF) and "manifold" with the same settings, both on the exact GP,
    so the kernel is their only difference."""
    agent = dict(agent, gp="exact")
    return {name: {"agent": agent}, "manifold": {"agent": dict(agent, kernel="manifold")}}


def preset_table(env: str, agent: str):
    """{preset name: entry} of ``agent`` on ``env`` (None: no presets)."""
    from trl_dgpq.envs import domain, split_name
    return domain(env).presets(agent, split_name(env)[1])


def default_preset(env: str) -> str:
    from trl_dgpq.envs import domain, split_name
    return domain(env).default_preset(split_name(env)[1])


def preset_overrides(env: str, agent: str, name=None):
    """(name, {"env": {...}, "agent": {...}}) of preset ``name`` (None: the env's default)."""
    table = preset_table(env, agent)
    if table is None:
        raise ValueError(f"no presets for agent {agent!r} on env {env!r}: add an entry to its domain's presets.py")
    name = name or default_preset(env)
    if name not in table:
        raise ValueError(f"unknown preset {name!r} for {agent} on {env}; choose from {sorted(table)}")
    entry = table[name]
    unknown = set(entry) - {"env", "agent"}
    if unknown:
        raise ValueError(f"preset {name!r}: sections must be 'env' and 'agent', got {sorted(unknown)}")
    return name, {"env": dict(entry.get("env", {})), "agent": dict(entry.get("agent", {}))}
