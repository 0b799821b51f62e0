"""Evaluate a trained agent: its last checkpoint, learning and exploration off, on
episodes its training never met.

For each job of a run (the run folder itself, or each ``jobs/*`` of a sweep experiment)
the agent is rebuilt from ``config.json`` and restored from ``checkpoint.pt`` (read
with ``weights_only=True``; the file is only read). The env is a fresh one whose
streams are keyed for evaluation (``SeedBatchedEnv.for_evaluation``): seed i's
evaluation episodes are the same in any batch and share no random numbers with its
training. The agent acts by ``exploit`` (DGPQ: Q̂'s greedy action; DQN: ε = 0; DDPG:
no OU noise) and ``observe`` is never called. The rows, one per episode as in
``episodes.csv``, go to ``eval.csv`` beside the run's ``episodes.csv``; a Ctrl-C keeps the
episodes already finished in ``eval.partial.csv`` (never in eval.csv, which is only ever a whole
evaluation).
"""
from __future__ import annotations

import json
from pathlib import Path
from typing import Iterator, List, Optional

import pandas as pd
import torch

from .experiment import build, describe
from .online import OnlineCollector, frame
from .runner import CHECKPOINT, RunError, RunFolder, write_csv

EVAL = "eval.csv"
PARTIAL = "eval.partial.csv"


class EvaluationInterrupted(KeyboardInterrupt):
    """Ctrl-C during ``evaluate``: the episodes finished by then are in ``path`` (None: none was)."""

    def __init__(self, path: Optional[Path], episodes: int):
        super().__init__(f"{episodes} evaluation episodes kept in {path}" if path else "no evaluation episode finished")
        self.path, self.episodes = path, episodes


class Frozen:
    """An agent that acts by its ``exploit`` and learns nothing."""

    def __init__(self, agent):
        self.agent = agent

    def act(self, td) -> torch.Tensor:
        return getattr(self.agent, "exploit", self.agent.act)(td)

    def observe(self, td, active=None) -> None:
        pass

    def episode_stats(self) -> dict:
        return self.agent.episode_stats()


def episode_steps(env, policy, td, row: Optional[int] = None) -> Iterator[tuple]:
    """Play on from ``td`` (a state the env just reset to) under ``policy`` (td -> actions):
    yield ``(td, nxt, done)`` after each step -- ``td`` with its action, ``nxt`` the step's
    "next" entries, ``done`` the seeds that have finished so far -- until seed row ``row``
    is done (every seed when ``row`` is None). No seed is reset on the way; the pictures and
    traces of the domains are drawn from these steps."""
    done = torch.zeros(env.batch_size[0], dtype=torch.bool)
    while True:
        td["action"] = policy(td)
        nxt = env.step(td)["next"]
        done = done | nxt["done"].reshape(-1)
        yield td, nxt, done
        if bool(done[row]) if row is not None else bool(done.all()):
            return
        td = nxt.exclude("reward", "done", "terminated", "truncated")


def job_folders(folder: Path) -> List[Path]:
    """The folders of ``folder``'s run holding a config.json and a checkpoint: the run itself,
    or the jobs of a sweep experiment (empty if none)."""
    folder = Path(folder)
    return [j for j in [folder, *sorted((folder / "jobs").glob("*"))]
            if (j / "config.json").is_file() and (j / CHECKPOINT).is_file()]


def jobs(folder: Path) -> List[Path]:
    """``job_folders``, or RunError (one line) if there is none."""
    found = job_folders(folder)
    if not found:
        raise RunError(f"{folder} holds no run with a checkpoint (config.json and {CHECKPOINT}): train it first")
    return found


def restore(job: Path):
    """(config, env, agent, checkpoint) of the run in ``job``: the agent as its last checkpoint
    left it, the env fresh (its training state is ``checkpoint["env"]``)."""
    config = json.loads((job / "config.json").read_text())
    state = RunFolder(job).load_checkpoint()  # the previous one if the latest is damaged, saying so
    if state is None:
        raise RunError(f"{job} holds no checkpoint")
    env, agent = build(config)
    agent.load_state_dict(state["agent"])
    return config, env, agent, state


def evaluate_job(job: Path, episodes: int, progress: bool = False, on_rows=None) -> pd.DataFrame:
    """``episodes`` evaluation episodes per seed of the run in ``job`` (``on_rows`` gets each
    step's finished episodes' rows as they end). The checkpoint is only read
    (tests/test_evaluate.py checks its bytes are unchanged)."""
    config, env, agent, _ = restore(job)
    env.for_evaluation()
    return OnlineCollector(env, Frozen(agent), episodes, progress=progress,
                           desc=f"evaluate {describe(config)}").run(on_rows=on_rows)


def evaluate(folder, episodes: int = 10, progress: bool = False, out=None) -> pd.DataFrame:
    """Evaluate every job of the run in ``folder``; writes ``eval.csv`` into ``out`` (default: the
    run's folder; another for a run one may not write into) and returns it. Ctrl-C raises
    ``EvaluationInterrupted`` after writing the episodes finished so far to ``eval.partial.csv``."""
    folder = Path(folder)
    target = Path(out) if out is not None else folder
    if int(episodes) != episodes or episodes < 1:
        raise ValueError(f"episodes must be a positive integer, got {episodes}")
    finished = []
    try:
        df = pd.concat([evaluate_job(j, int(episodes), progress, finished.extend) for j in jobs(folder)])
    except KeyboardInterrupt:
        if finished:
            target.mkdir(parents=True, exist_ok=True)
            write_csv(frame(finished), target / PARTIAL)
        raise EvaluationInterrupted(target / PARTIAL if finished else None, len(finished)) from None
    df = df.sort_values(["seed", "episode"]).reset_index(drop=True)   # (seed, episode) is unique: any sort
    target.mkdir(parents=True, exist_ok=True)
    write_csv(df, target / EVAL)
    (target / PARTIAL).unlink(missing_ok=True)   # a whole evaluation replaces an interrupted one
    return df


__all__ = ["EVAL", "EvaluationInterrupted", "Frozen", "PARTIAL", "episode_steps", "evaluate", "evaluate_job", "frame", "job_folders", "jobs",
           "restore"]
