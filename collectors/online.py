"""Lock-step collection for online learners on a seed-batched env.

TorchRL's collectors hand a frozen policy to worker processes and learn from
batches afterwards; DGPQ learns after every transition, so here the learner runs
inline: act -> ``env.step_and_maybe_reset`` -> observe, for all seeds at once.
Seeds that have finished their episodes stay in the batch (the env is
batch-locked) but are masked out of learning and bookkeeping.

Time is measured per batched step (wall: ``perf_counter``, CPU: ``process_time``
of the whole process) and shared equally among the seeds active in that step,
so ``wall_s`` / ``cpu_s`` of an episode is that seed's share of the batch's cost.
"""
from __future__ import annotations

import time
from typing import Optional, Protocol

import pandas as pd
import torch
from tqdm.auto import tqdm


class OnlineAgent(Protocol):
    def act(self, s: torch.Tensor) -> torch.Tensor: ...
    def observe(self, s, a, r, s_next, terminal, active) -> dict: ...
    def episode_stats(self) -> dict: ...


class OnlineCollector:
    """Runs ``episodes`` episodes for every seed of ``env`` (or stops after
    ``max_total_steps`` batched steps) and returns one row per finished episode.

    ``step_seconds`` holds the wall time of every batched step (for benchmarks).
    """

    def __init__(self, env, agent: OnlineAgent, episodes: int, max_total_steps: Optional[int] = None,
                 progress: bool = True, desc: str = "episodes"):
        if int(episodes) != episodes or episodes < 1:
            raise ValueError(f"episodes must be a positive integer, got {episodes}")
        self.env, self.agent, self.episodes = env, agent, int(episodes)
        self.max_total_steps = max_total_steps
        self.progress, self.desc = progress, desc
        self.step_seconds: list[float] = []

    def run(self) -> pd.DataFrame:
        env, agent = self.env, self.agent
        S = env.batch_size[0]
        seeds = list(getattr(env, "seeds", range(S)))
        zeros = lambda dtype=torch.float64: torch.zeros(S, dtype=dtype)  # noqa: E731
        episode, steps, ret, wall, cpu = zeros(torch.long), zeros(torch.long), zeros(), zeros(), zeros()
        active = torch.ones(S, dtype=torch.bool)
        rows = []
        bar = tqdm(total=S * self.episodes, desc=self.desc, disable=not self.progress, leave=False, mininterval=0.5)
        td = env.reset()
        total = 0
        while active.any() and (self.max_total_steps is None or total < self.max_total_steps):
            t0, c0 = time.perf_counter(), time.process_time()
            s = td.get("observation")
            a = agent.act(s)
            td.set("action", a)
            td, td_next = env.step_and_maybe_reset(td)
            nxt = td.get("next")
            r = nxt.get("reward")[:, 0]
            terminated = nxt.get("terminated")[:, 0]
            agent.observe(s, a, r, nxt.get("observation"), terminated, active)
            dt, dc = time.perf_counter() - t0, time.process_time() - c0
            self.step_seconds.append(dt)
            total += 1
            n_active = int(active.sum())
            steps += active
            ret += torch.where(active, r.to(torch.float64), 0.0)
            wall += active * (dt / n_active)
            cpu += active * (dc / n_active)
            finished = nxt.get("done")[:, 0] & active
            if finished.any():
                episode += finished
                stats = {k: v.tolist() for k, v in agent.episode_stats().items()}
                for i in finished.nonzero()[:, 0].tolist():
                    rows.append(dict(seed=seeds[i], episode=int(episode[i]), steps=int(steps[i]),
                                     **{"return": float(ret[i])}, terminated=bool(terminated[i]),
                                     wall_s=float(wall[i]), cpu_s=float(cpu[i]),
                                     us_per_step=float(wall[i]) / int(steps[i]) * 1e6,
                                     **{k: v[i] for k, v in stats.items()}))
                steps[finished], ret[finished], wall[finished], cpu[finished] = 0, 0.0, 0.0, 0.0
                active &= episode < self.episodes
                bar.update(int(finished.sum()))
                bar.set_postfix(steps=total)
            td = td_next
        bar.close()
        cols = ["seed", "episode", "steps", "return", "terminated", "wall_s", "cpu_s", "us_per_step"]
        df = pd.DataFrame(rows, columns=cols + [c for c in (rows[0] if rows else {}) if c not in cols])
        return df.sort_values(["seed", "episode"], kind="stable").reset_index(drop=True)
