"""One experiment = (env, preset, overrides, seeds, episodes) -> per-episode DataFrame.

``resolve_config`` turns user choices into a complete, validated, JSON-able dict
(what ``config.json`` records); ``run_experiment`` builds the seed-batched env
and DGPQ agent from such a dict and runs them in lock-step. Everything that
varies between runs lives in the dict, so a run can be repeated from its
``config.json`` alone, and a batch of seeds can later be shipped to another
process or machine as (config, seed list).
"""
from __future__ import annotations

import copy
import re
from typing import Iterable, List, Optional

import pandas as pd

from envs import ENVS
from trl_dgpq.dgpq import DGPQ, DGPQConfig

from .online import OnlineCollector

TIMING_COLUMNS = ("wall_s", "cpu_s", "us_per_step")


def parse_seeds(text: str) -> List[int]:
    """'N' -> 0..N-1; 'A-B' -> A..B inclusive; 'a,b,c' -> that list."""
    text = str(text).strip()
    if re.fullmatch(r"\d+", text):
        n = int(text)
        if n < 1:
            raise ValueError("--seeds count must be >= 1")
        return list(range(n))
    m = re.fullmatch(r"(\d+)\s*-\s*(\d+)", text)
    if m:
        a, b = int(m.group(1)), int(m.group(2))
        if b < a:
            raise ValueError(f"--seeds range {text!r} is empty")
        return list(range(a, b + 1))
    if re.fullmatch(r"\d+(\s*,\s*\d+)+,?", text):
        seeds = [int(s) for s in text.split(",") if s.strip()]
        if len(set(seeds)) != len(seeds):
            raise ValueError(f"--seeds {text!r} repeats a seed")
        return seeds
    raise ValueError(f"--seeds must be a count N, a range A-B or a comma list, got {text!r}")


def resolve_config(env: str = "square", preset: Optional[str] = None, seeds: Iterable[int] = range(8),
                   episodes: int = 30, agent: Optional[dict] = None, env_kwargs: Optional[dict] = None) -> dict:
    """Preset + overrides -> validated config dict (agent values resolved, e.g. Section 5)."""
    if env not in ENVS:
        raise ValueError(f"unknown env {env!r}; choose from {sorted(ENVS)}")
    env_cls, presets = ENVS[env]
    preset = preset or next(iter(presets))
    if preset not in presets:
        raise ValueError(f"unknown preset {preset!r} for env {env!r}; choose from {sorted(presets)}")
    base = copy.deepcopy(presets[preset])
    agent_d = {**base["agent"], **(agent or {})}
    # Asking for Section 5 (eps/delta) without explicit sigma_tol2/eps1 derives both.
    if agent and ({"eps", "delta"} & set(agent)):
        for k in ("sigma_tol2", "eps1"):
            if k not in agent:
                agent_d[k] = None
    env_d = {**base["env"], **(env_kwargs or {})}
    seeds = [int(s) for s in seeds]
    if not seeds or min(seeds) < 0 or len(set(seeds)) != len(seeds):
        raise ValueError("seeds must be distinct non-negative integers")
    if int(episodes) != episodes or episodes < 1:
        raise ValueError(f"episodes must be >= 1, got {episodes}")
    probe = env_cls(seeds=[0], **env_d)  # validates env settings, gives the action count
    num_actions = int(probe.action_spec.space.n)
    cfg = DGPQConfig.from_dict(agent_d).resolve(num_actions)
    return dict(env=env, preset=preset, env_kwargs=env_d, agent=cfg.to_dict(), seeds=seeds,
                episodes=int(episodes))


def build(config: dict, seeds: Optional[List[int]] = None):
    """The env and agent for ``seeds`` (default: the config's)."""
    seeds = config["seeds"] if seeds is None else seeds
    env_cls, _ = ENVS[config["env"]]
    env = env_cls(seeds=seeds, **config["env_kwargs"])
    obs_dim = env.observation_spec["observation"].shape[-1]
    num_actions = int(env.action_spec.space.n)
    agent = DGPQ(DGPQConfig.from_dict(config["agent"]), seeds, obs_dim, num_actions)
    return env, agent


def run_experiment(config: dict, progress: bool = True, max_total_steps: Optional[int] = None,
                   seeds: Optional[List[int]] = None) -> pd.DataFrame:
    """Run all (or the given) seeds of ``config`` in one batch; one row per episode."""
    env, agent = build(config, seeds)
    collector = OnlineCollector(env, agent, config["episodes"], max_total_steps=max_total_steps,
                                progress=progress, desc=f"{config['env']}/{config['preset']}")
    df = collector.run()
    df.attrs["step_seconds"] = collector.step_seconds
    return df
