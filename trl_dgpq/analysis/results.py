"""One row per experiment: the summary the repository keeps under ``results/`` (never the runs).

``report`` writes ``results.csv`` beside ``compare.md``, ``reproduce`` beside REPORT.md; the
columns are ``COLUMNS`` in both, so a committed file and the next run's cannot drift apart
(tests/test_results.py). Each row says what ran (env, agent, preset, seeds, length), what
came out (the domain's measure, each seed's mean over its last ``last`` episodes within the
budget -- ``summary.last_episodes``, as the at-budget columns --, then the median, and the
IQM with its 95 % bootstrap CI, over seeds), what it cost (microseconds per seed-step), what of
the env's model it uses (``uses_model``: empty for a model-free run), the commits of the
code that made its rows (each job's, in full, once; ``-dirty`` if its tree was), and the
command that runs it again: ``train.py`` with the run's preset and a ``--set`` for every
setting that differs from it.
"""
from __future__ import annotations

import csv
from pathlib import Path
from typing import Optional

import numpy as np

from .published import commits_of
from .stats import iqm
from .summary import last_episodes, ms_per_seed_step

COLUMNS = ("experiment", "env", "agent", "preset", "seeds", "episodes", "env_steps", "measure", "last",
           "median", "iqm", "iqm_low", "iqm_high", "us_per_seed_step", "uses_model", "commit", "command")


def seeds_text(seeds) -> str:
    """As --seeds reads it back: 0-9 for a range (5-5 for seed 5 alone: "5" would be 5 seeds),
    else 0,2,5."""
    seeds = list(seeds)
    if seeds == list(range(seeds[0], seeds[-1] + 1)):
        return f"{seeds[0]}-{seeds[-1]}"
    return ",".join(map(str, seeds))


def cli_value(value) -> str:
    """A setting's value as ``--set`` reads it back."""
    if value is None:
        return "none"
    if isinstance(value, bool):
        return str(value).lower()
    if isinstance(value, (list, tuple)):
        return ",".join(cli_value(v) for v in value)
    return repr(value) if isinstance(value, float) else str(value)


def differences(recorded: dict, preset: dict, prefix: str) -> list:
    """``--set`` items for the settings where the recorded section differs from the preset's."""
    out = []
    for key, value in recorded.items():
        if isinstance(value, dict):
            out += differences(value, preset.get(key, {}), f"{prefix}{key}.")
        elif preset.get(key) != value:
            out.append(f"{prefix}{key}={cli_value(value)}")
    return out


def train_command(config: dict) -> str:
    """The train.py command that resolves to ``config`` (its run, env and agent sections)."""
    from trl_dgpq.collectors.experiment import resolve_config
    run = config["run"]
    length = {"episodes": run["episodes"], "env_steps": run["env_steps"]}
    base = resolve_config(env=run["env"], agent=run["agent"], preset=run["preset"], seeds=run["seeds"], **length)
    words = ["python scripts/train.py", f"--env {run['env']}", f"--agent {run['agent']}", f"--preset {run['preset']}",
             f"--seeds {seeds_text(run['seeds'])}", f"--episodes {run['episodes']}"]
    if run["env_steps"]:
        words.append(f"--env-steps {run['env_steps']}")
    for section in ("env", "agent"):
        words += [f"--set {item}" for item in differences(config[section], base[section], f"{section}.")]
    return " ".join(words)


def row(experiment: str, run, last: Optional[int] = None, command: Optional[str] = None) -> dict:
    """The row of one run (``analysis.runs.Run``): its measure over each seed's last ``last``
    episodes (default: the domain's ``DEFAULT_LAST``, else 10)."""
    column, _ = run.measure()
    if last is None:
        last = getattr(run.domain.analysis(), "DEFAULT_LAST", 10)
    budget = run.config["run"].get("env_steps", 0)
    per_seed = last_episodes(run.df, last, budget).groupby("seed")[column].mean()
    point, low, high = iqm(per_seed.to_numpy())
    # a sweep's experiment: its config is its first job's, its episodes every job's seeds
    recorded = run.config["run"]
    cfg = {**run.config, "run": {**recorded, "seeds": [int(s) for s in per_seed.index],
                                 "episodes": recorded.get("episodes", int(run.df.episode.max())),
                                 "env_steps": recorded.get("env_steps", 0)}}
    from trl_dgpq.envs import model_knowledge
    if command is None:
        try:
            command = train_command(cfg)
        except (ValueError, KeyError) as err:  # a preset since removed: say so, not a wrong command
            command = f"(cannot be rebuilt here: {err})"
    return dict(experiment=experiment, env=run.env, agent=run.agent, preset=run.preset,
                seeds=seeds_text(cfg["run"]["seeds"]), episodes=cfg["run"]["episodes"],
                env_steps=cfg["run"]["env_steps"], measure=column, last=last,
                median=float(np.median(per_seed)), iqm=point, iqm_low=low, iqm_high=high,
                us_per_seed_step=round(ms_per_seed_step(run.df) * 1e3, 1),
                uses_model="; ".join(model_knowledge(run.config)),
                commit=commit_text(run), command=command)


def commit_text(run) -> str:
    """The commits of the code that made the run's rows (its jobs'; an experiment's own config
    records the commit its sweep was laid out or merged at), each in full and once."""
    return " ".join(dict.fromkeys(commits_of(run, length=40)))


def write(rows: list, path: Path) -> Path:
    with open(path, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=COLUMNS)
        w.writeheader()
        w.writerows({k: (f"{v:.10g}" if isinstance(v, float) else v) for k, v in r.items()} for r in rows)
    return path
