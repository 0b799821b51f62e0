"""One experiment = a resolved config -> seed-batched env + agent -> per-episode rows.

``resolve_config`` turns user choices (preset, ``--set`` overrides, or a recorded
``config.json``) into a complete, validated, JSON-able dict of three sections:

    {"run": RunConfig fields, "env": the env's Config fields, "agent": the agent's Config fields}

Defaults come from the dataclasses only; presets (each domain's ``presets.py``) and
overrides are applied on top. What the agent needs to know of the env is one
``EnvInfo`` made from the env's class and config (no env is built for it).
``build`` makes the env and agent for a config and a seed list, so a batch of seeds
can be shipped to another process as (config, seeds).
"""
from __future__ import annotations

import logging
import os
import re
from dataclasses import dataclass
from typing import Any, Dict, List, Optional, Tuple

import pandas as pd

from trl_dgpq.agents import agent_class, agent_names, check_agent_name
from trl_dgpq.config import check_config, find_leaf, from_dict, leaves, setting, to_dict, with_overrides
from trl_dgpq.envs import check_env_name, domains, env_class, env_configs, make_env
from trl_dgpq.presets import preset_overrides, preset_table

from .online import OnlineCollector

TIMING_COLUMNS = ("wall_s", "cpu_s", "us_per_step")
SECTIONS = ("run", "env", "agent")


def quiet_torchrl() -> None:
    """TorchRL logs one INFO line per replay buffer; commands show warnings only. (Its
    logger's level is set when torchrl is imported, so import it first.)"""
    import torchrl  # noqa: F401
    logging.getLogger("torchrl").setLevel(logging.WARNING)


def parse_seeds(text) -> List[int]:
    """'N' -> 0..N-1; 'A-B' -> A..B inclusive; 'a,b,c' -> that list (a list or range is checked)."""
    if not isinstance(text, (str, int)):  # a list, tuple or range of seeds
        seeds = list(text)
        if not seeds or not all(isinstance(s, int) and not isinstance(s, bool) and s >= 0 for s in seeds):
            raise ValueError(f"seeds must be non-negative integers, got {seeds}")
        if len(set(seeds)) != len(seeds):
            raise ValueError(f"seeds {seeds} repeat a seed")
        return seeds
    text = str(text).strip()
    if re.fullmatch(r"\d+", text):
        n = int(text)
        if n < 1:
            raise ValueError("seeds count must be >= 1")
        return list(range(n))
    m = re.fullmatch(r"(\d+)\s*-\s*(\d+)", text)
    if m:
        a, b = int(m.group(1)), int(m.group(2))
        if b < a:
            raise ValueError(f"seeds range {text!r} is empty")
        return list(range(a, b + 1))
    if re.fullmatch(r"\d+(\s*,\s*\d+)+,?", text):
        return parse_seeds([int(s) for s in text.split(",") if s.strip()])
    raise ValueError(f"seeds must be a count N, a range A-B or a comma list, got {text!r}")


@dataclass
class RunConfig:
    """What to run."""
    env: str = setting("square", f"environment: {', '.join(e for d in domains() for e in d.examples())} "
                                  "(gym:ID: any gymnasium id with discrete actions)", parse=check_env_name)
    agent: str = setting("dgpq", f"agent: {', '.join(agent_names())}", parse=check_agent_name)
    preset: Optional[str] = setting(None, "named settings of (env, agent) in the env's domain's presets.py "
                                          "(default: the env's default preset)")
    seeds: Tuple[int, ...] = setting(tuple(range(8)), "count N (seeds 0..N-1), range A-B (inclusive) or "
                                                      "list a,b,c; all run in one batch",
                                     parse=lambda v: tuple(parse_seeds(v)))
    episodes: int = setting(50, "episodes per seed (with --env-steps and no --episodes: until the budget)",
                            within="[1, inf)")
    env_steps: int = setting(0, "budget of environment steps per seed: a seed stops at the end of the episode "
                                "that reaches it (0: none; episodes still caps)", within="[0, inf)")
    checkpoint_every: int = setting(10, "checkpoint every K episodes per seed (0: only on interrupt and at the end)",
                                    within="[0, inf)")
    max_memory: float = setting(0.0, "GiB this process may use: a run whose storage would grow past it (or past "
                                     "the machine's available memory, always checked) stops first, checkpointed "
                                     "(0: no limit of its own)", within="[0, inf)")
    threads: int = setting(1, "torch intra-op threads (docs/running-at-scale.md, \"Threads\": 1 was fastest for every agent, seed "
                              "count and load measured but one; 2 were 2-50x slower on a loaded machine)",
                           within="[1, inf)")


def classes(run: dict):
    """(env class, agent class) of a run section."""
    return env_class(run["env"]), agent_class(run["agent"], run["env"])


def split_overrides(settings: Dict[str, Any], env_cls, agent_cls) -> Dict[str, Dict[str, Any]]:
    """{key: value} -> {"run"|"env"|"agent": {leaf key: value}}. A key is a setting name
    (``noise_var``), a dotted path (``gp.noise_var``) or either behind a section
    (``agent.noise_var``)."""
    owners = {"run": RunConfig, "env": env_cls.Config, "agent": agent_cls.Config}
    out = {s: {} for s in SECTIONS}
    for key, value in settings.items():
        head, _, rest = key.partition(".")
        if head in owners and rest:
            places = [(head, find_leaf(owners[head], rest))]
        else:
            places = [(s, find_leaf(cls, key)) for s, cls in owners.items()]
        places = [(s, leaf) for s, leaf in places if leaf is not None]
        if not places:
            last = key.rpartition(".")[2]
            hint = f" (did you mean {last!r}?)" if last != key and any(
                find_leaf(cls, last) for cls in owners.values()) else ""
            raise ValueError(f"unknown setting {key!r} for env {env_cls.__name__} and agent {agent_cls.__name__}"
                             + hint)
        if len(places) > 1:
            raise ValueError(f"setting {key!r} is ambiguous: say {' or '.join(s + '.' + key for s, _ in places)}")
        section, leaf = places[0]
        out[section][leaf.key] = value
    return out


def run_settings(settings: Dict[str, Any]) -> Dict[str, Any]:
    """The settings among ``settings`` that belong to RunConfig (``episodes``, ``run.episodes``);
    they decide which env and agent the others belong to."""
    out = {}
    for key, value in settings.items():
        name = key.removeprefix("run.")
        if "." not in name and find_leaf(RunConfig, name):
            out[name] = value
    return out


def resolve_config(settings: Optional[Dict[str, Any]] = None, base: Optional[dict] = None, **kw) -> dict:
    """Validated, complete config dict. ``settings`` (and keyword arguments) are
    overrides by setting name, e.g. ``resolve_config(preset="report", seeds=[0], gp="exact")``;
    ``base`` is a recorded config (``config.json``) to start from instead of a preset.
    Raises ValueError with one line for anything wrong."""
    settings = {**(settings or {}), **kw}
    start = from_dict(RunConfig, base["run"]) if base else RunConfig()
    given_run = run_settings(settings)
    run = check_config(with_overrides(start, given_run))
    if run.env_steps and "episodes" not in given_run and not base:
        # a budget alone is enough: a seed's budget of N steps ends within N episodes
        run = with_overrides(run, {"episodes": run.env_steps})
    if base and (run.env, run.agent) != (base["run"]["env"], base["run"]["agent"]):
        raise ValueError("a recorded config keeps its env and agent; start a new run to change them")
    env_cls, agent_cls = classes(to_dict(run))
    given = split_overrides(settings, env_cls, agent_cls)
    if base:
        env_cfg = from_dict(env_cls.Config, base["env"])
        agent_cfg = from_dict(agent_cls.Config, base["agent"])
    else:
        if preset_table(run.env, run.agent) is None:  # say why they do not go together, if the agent knows
            agent_cls.resolve_config(agent_cls.Config(), env_cls.describe())
        name, preset = preset_overrides(run.env, run.agent, run.preset)
        run = with_overrides(run, {"preset": name})
        env_cfg = with_overrides(env_cls.Config(), preset["env"])
        agent_cfg = with_overrides(agent_cls.Config(), preset["agent"])
    implied = getattr(agent_cls.Config, "implied", lambda given: {})(given["agent"])
    env_cfg = with_overrides(env_cfg, given["env"])
    info = env_cls.describe(env_cfg)  # checks the env's settings
    agent_cfg = agent_cls.resolve_config(with_overrides(agent_cfg, {**implied, **given["agent"]}), info)
    return {"run": to_dict(run), "env": to_dict(env_cfg), "agent": to_dict(agent_cfg)}


def use_threads(config: dict) -> None:
    """Set torch's intra-op threads to the config's (a config from before the setting: leave them)."""
    n = config["run"].get("threads")
    if n:
        import torch
        torch.set_num_threads(int(n))


def load_sections(config: dict):
    """(RunConfig, env config, agent config) objects of a config dict."""
    unknown = set(config) - set(SECTIONS) - {"versions", "git", "lengthened", "model_knowledge"}
    if unknown or not set(SECTIONS) <= set(config):
        raise ValueError(f"a config needs sections {list(SECTIONS)}, got {sorted(config)}")
    env_cls, agent_cls = classes(config["run"])
    return (from_dict(RunConfig, config["run"]), from_dict(env_cls.Config, config["env"]),
            from_dict(agent_cls.Config, config["agent"]))


def build(config: dict, seeds: Optional[List[int]] = None, device="cpu"):
    """The env and agent of ``config`` for ``seeds`` (default: the config's)."""
    run, env_cfg, agent_cfg = load_sections(config)
    seeds = list(run.seeds) if seeds is None else list(seeds)
    env = make_env(run.env, env_cfg, seeds, device=device)
    return env, classes(config["run"])[1].make(agent_cfg, env.info, seeds)


def memory_estimate(config: dict) -> int:
    """Bytes the agent's state takes at the start, for all seeds."""
    run, env_cfg, agent_cfg = load_sections(config)
    env_cls, agent_cls = classes(config["run"])
    return int(agent_cls.memory_bytes(agent_cfg, env_cls.describe(env_cfg), len(run.seeds)))


def available_memory() -> Optional[int]:
    """MemAvailable of this machine in bytes (None if unknown)."""
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    return None


def check_memory(config: dict) -> None:
    """Refuse (ValueError) a config whose state would not fit in this machine's memory."""
    need, have = memory_estimate(config), available_memory()
    if have is not None and need > have:
        raise ValueError(f"this run needs about {need / 2**30:.3g} GiB for its agents' state at the start, "
                         f"{have / 2**30:.3g} GiB is available: fewer seeds, a smaller budget or capacity")


def resident_bytes() -> int:
    """This process's resident memory (Linux /proc; 0 if unknown)."""
    try:
        with open("/proc/self/statm") as f:
            return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")
    except (OSError, ValueError, IndexError):
        return 0


class MemoryLimit(ValueError):
    """The agent's storage would grow past the memory it may use."""


def memory_guard(agent, max_gib: float):
    """A check for before each step (None for an agent whose storage never grows): raises
    MemoryLimit, naming what would not fit and how to go on, if the next growth would."""
    growth = getattr(agent, "growth_bytes", None)
    if growth is None:
        return None

    def check() -> None:
        need = growth()
        if not need:
            return
        have = available_memory()
        over = []
        if have is not None and need > have:
            over.append(f"{have / 2**30:.3g} GiB available")
        if max_gib and resident_bytes() + need > max_gib * 2**30:
            over.append(f"--max-memory {max_gib:g} GiB (this process holds {resident_bytes() / 2**30:.3g})")
        if over:
            raise MemoryLimit(f"the agents' storage must grow by {need / 2**30:.3g} GiB, past "
                              f"{' and '.join(over)}; continue with fewer seeds per run, a smaller budget, the "
                              "sparse GP (--gp sparse), or more --max-memory")
    return check


def describe(config: dict) -> str:
    run = config["run"]
    return f"{run['env']}/{run['agent']}/{run['preset']}"


def run_experiment(config: dict, progress: bool = True, max_total_steps: Optional[int] = None,
                   seeds: Optional[List[int]] = None) -> pd.DataFrame:
    """Run all (or the given) seeds of ``config`` in one batch, in memory; one row per
    episode. (``trl_dgpq.collectors.runner`` runs into a folder, with checkpoints.)"""
    check_memory(config)
    use_threads(config)
    env, agent = build(config, seeds)
    run = load_sections(config)[0]
    collector = OnlineCollector(env, agent, run.episodes, max_total_steps=max_total_steps,
                                progress=progress, desc=describe(config), env_steps=run.env_steps)
    try:
        df = collector.run()
    finally:  # now, not when collected: a push env holds a physics client per seed
        env.close(raise_if_closed=False)
    df.attrs["step_seconds"] = collector.step_seconds
    return df


def cli_leaves():
    """Every setting of RunConfig and of every registered env and agent config, by key
    (first one wins for help text): what ``scripts/train.py`` builds its flags from."""
    return {key: owners[0][1] for key, owners in cli_owners().items()}


def cli_owners():
    """{key: [(config class name, leaf), ...]}: every config that has a setting of that name
    (``--reward`` belongs to several envs, with different defaults and choices)."""
    out = {}
    for cls in [RunConfig] + env_configs() + [agent_class(a).Config for a in agent_names()]:
        for leaf in leaves(cls):
            out.setdefault(leaf.key, []).append((cls.__name__, leaf))
    return out
