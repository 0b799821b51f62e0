"""Named settings per (env, agent): overrides of the config dataclasses' defaults, and
nothing else. Each domain keeps its own in ``envs/<domain>/presets.py`` (``PRESETS``
by agent, and ``DEFAULT``, the default preset's name); this module holds the
building blocks several domains share and the lookup.

Keys are setting names as on the command line (``noise_var``, or dotted paths).

A study's best trial (``trl-dgpq tune --write-preset [NAME]``) is a preset too, named NAME or
else ``tuned`` when the study ran on the env's default preset and ``<preset>-tuned`` otherwise
(the noisy square's is "noisy-tuned", so it never replaces the square's "tuned"): it lives in
``envs/<domain>/tuned.json`` beside the domain's presets, keyed by env name, agent and
preset name, with its provenance, and the lookup below adds it to every domain's table.
"""
from __future__ import annotations

import importlib
import json
import os
import re
from pathlib import Path

# DQN on the suite's own envs (not tuned; docs/agents/neural.md "DQN"): rl-baselines3-zoo's
# CartPole-scale settings shrunk to these small tasks -- a (64, 64) network, one update per
# step from the 256th, a target copy every 100 steps, epsilon down to 0.05 over 2,000 steps.
SMALL_DQN = dict(hidden=(64, 64), lr=1e-3, batch_size=64, buffer_size=10_000, learning_starts=256, train_freq=1,
                 gradient_steps=1, target_update_interval=100, exploration_steps=2_000, eps_end=0.05)


def rbf_and_manifold(name: str, **agent) -> dict:
    """DGPQ presets ``name`` (RBF) and "manifold" with the same settings, both on the exact GP,
    so the kernel is their only difference."""
    agent = dict(agent, gp="exact")
    return {name: {"agent": agent}, "manifold": {"agent": dict(agent, kernel="manifold")}}


TUNED = "tuned"


def tuned_file(env: str) -> Path:
    """The tuned presets of ``env``'s domain: ``envs/<domain>/tuned.json``, {env: {agent:
    {"preset": {"env": ..., "agent": ...}, "provenance": {...}}}}."""
    from trl_dgpq.envs import domain
    return Path(importlib.import_module(domain(env).package).__file__).parent / "tuned.json"


def tuned_name(env: str, base: str) -> str:
    """The name of a study's preset run on preset ``base`` of ``env``."""
    return TUNED if base == default_preset(env) else f"{base}-{TUNED}"


def check_preset_name(env: str, agent: str, name: str) -> None:
    """A study's preset may take any plain name but one of the domain's own presets of ``agent``
    (it would hide it); rewriting an earlier study's preset of that name is allowed."""
    from trl_dgpq.envs import domain, split_name
    if not re.fullmatch(r"[A-Za-z0-9][A-Za-z0-9_.-]*", name):
        raise ValueError(f"a preset name is letters, digits and _ . - (not first), got {name!r}")
    if name in (domain(env).presets(agent, split_name(env)[1]) or {}):
        raise ValueError(f"{name!r} is a preset of {agent} on {env} in its domain's presets.py: "
                         "choose another name for the study's")


def tuned_entries(env: str) -> dict:
    """{agent: {preset name: {"preset": ..., "provenance": ...}}} of ``env`` in its domain's
    tuned.json."""
    path = tuned_file(env)
    try:
        return json.loads(path.read_text()).get(env, {})
    except FileNotFoundError:
        return {}
    except (OSError, ValueError, AttributeError) as err:
        raise ValueError(f"cannot read the tuned presets in {path}: {err}") from None


def write_tuned(env: str, agent: str, name: str, preset: dict, provenance: dict) -> Path:
    """Record ``preset`` as ``env``'s preset ``name`` of ``agent`` (the file's other entries kept);
    the file is replaced whole (a temporary file, then a rename)."""
    path = tuned_file(env)
    data = json.loads(path.read_text()) if path.exists() else {}
    data.setdefault(env, {}).setdefault(agent, {})[name] = {"preset": preset, "provenance": provenance}
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    tmp.write_text(json.dumps(data, indent=2, sort_keys=True) + "\n")
    os.replace(tmp, path)
    return path


def preset_table(env: str, agent: str):
    """{preset name: entry} of ``agent`` on ``env``, with the tuned presets studies wrote (None:
    no presets)."""
    from trl_dgpq.envs import domain, split_name
    table = domain(env).presets(agent, split_name(env)[1])
    tuned = tuned_entries(env).get(agent)
    return table if not tuned else {**(table or {}), **{name: e["preset"] for name, e in tuned.items()}}


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
