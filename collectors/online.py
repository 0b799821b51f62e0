"""Lock-step collection for online learners on a seed-batched env.

act -> ``env.step_and_maybe_reset`` -> observe, for all seeds at once, after every
transition. Why not TorchRL's ``Collector``: it does run the policy in-process, so
a learner could update between its batches, but it counts frames, not episodes:
it cannot stop each seed after exactly ``episodes`` episodes while the others go
on, nor mask finished seeds out of learning, and its per-batch bookkeeping
(trajectory ids, step counts, batch assembly) would be paid on every single step
(measured with ``frames_per_batch=S``, 8 seeds: 2-3x the cost of stepping the env
in this loop, about 0.5 ms more per batched step).
Seeds that have finished stay in the batch (the env is batch-locked) but are
masked out of learning and bookkeeping.

Time is measured per batched step (wall: ``perf_counter``, CPU: ``process_time``
of the whole process) and shared equally among the seeds active in that step,
so ``wall_s`` / ``cpu_s`` of an episode is that seed's share of the batch's cost.

The collector's state (the current observation TensorDict, per-seed episode
counters and accumulators) saves and restores with ``state_dict``, so a run can
stop after any step and continue exactly.

Lengthening a run (more episodes, a larger budget) must continue each seed from the
step at which it stopped: a stopped seed's env and agent go on stepping with the
batch, so a later state no longer holds where it stopped. ``stopped_at`` records the
batched step at which each seed stopped, and ``first_stop`` says when a state is the
one to keep for that: seeds stopped in the step just taken, and none before, so every
stopped seed is still where it stopped. ``reactivate`` lets them go on.
"""
from __future__ import annotations

import time
from typing import Callable, List, Optional

import pandas as pd
import torch
from tensordict import TensorDict
from tqdm.auto import tqdm


class NonFiniteError(FloatingPointError):
    """The env produced NaN or inf."""


COLUMNS = ["seed", "episode", "steps", "return", "terminated", "wall_s", "cpu_s", "us_per_step"]


class OnlineCollector:
    """Runs ``episodes`` episodes for every seed of ``env`` (or stops after
    ``max_total_steps`` batched steps in one ``run`` call) and returns one row per
    finished episode. With ``env_steps`` > 0, a seed also stops at the end of the
    episode in which its environment steps (all episodes together) reach it: a budget
    of samples, for comparing learners by the experience they had.

    ``step_seconds`` holds the wall time of every batched step (for benchmarks; with
    ``time_steps=False`` it stays empty: a long run would hold a float per step, 35 MiB
    per million steps).
    """

    ACCUMULATORS = ("episode", "steps", "ret", "wall", "cpu", "active", "env_steps_done", "stopped_at")

    def __init__(self, env, agent, episodes: int, max_total_steps: Optional[int] = None,
                 progress: bool = True, desc: str = "episodes", env_steps: int = 0,
                 before_step: Optional[Callable[[], None]] = None, time_steps: bool = True):
        if int(episodes) != episodes or episodes < 1:
            raise ValueError(f"episodes must be a positive integer, got {episodes}")
        if int(env_steps) != env_steps or env_steps < 0:
            raise ValueError(f"env_steps must be a non-negative integer, got {env_steps}")
        self.env, self.agent, self.episodes, self.env_steps = env, agent, int(episodes), int(env_steps)
        self.before_step = before_step  # e.g. the memory guard: may raise before anything changes
        self.max_total_steps = max_total_steps
        self.progress, self.desc = progress, desc
        self.step_seconds: list[float] = []
        self.time_steps = time_steps
        S = env.batch_size[0]
        self.seeds = list(getattr(env, "seeds", range(S)))
        zeros = lambda dtype=torch.float64: torch.zeros(S, dtype=dtype)  # noqa: E731
        self.episode, self.steps, self.env_steps_done = zeros(torch.long), zeros(torch.long), zeros(torch.long)
        self.ret, self.wall, self.cpu = zeros(), zeros(), zeros()
        self.active = torch.ones(S, dtype=torch.bool)
        self.stopped_at = torch.full((S,), -1, dtype=torch.long)  # the batched step a seed stopped at; -1 active
        self.total = 0      # batched steps so far
        self.stopped_now = False  # seeds stopped in the step just taken
        self.td = None      # the current observation TensorDict (None: reset first)

    @property
    def finished(self) -> bool:
        return not bool(self.active.any())

    @property
    def episodes_done(self) -> int:
        return int(self.episode.sum())

    def run(self, on_rows: Optional[Callable[[List[dict]], None]] = None,
            after_step: Optional[Callable[["OnlineCollector"], bool]] = None, keep: bool = True) -> pd.DataFrame:
        """Collect until every seed has finished its episodes. After each batched step,
        ``on_rows(rows)`` gets the rows of the episodes that ended in it, then
        ``after_step(self)`` may return True to stop early (``run`` again continues).
        Returns the rows of this call, sorted by seed and episode; with ``keep=False`` none
        are kept (a caller that writes them through ``on_rows`` holds no row in memory)."""
        env, agent = self.env, self.agent
        S = env.batch_size[0]
        rows = []
        # progress in seed-episodes, or with a budget in seed-steps (each seed's counted up to its budget)
        budget = self.env_steps
        bar = tqdm(total=S * (budget or self.episodes), initial=self._progress(), desc=self.desc,
                   unit="seed-steps" if budget else "seed-episodes", unit_scale=bool(budget),
                   disable=not self.progress, leave=False, mininterval=0.5)
        td = env.reset() if self.td is None else self.td
        steps_here = 0
        while self.active.any() and (self.max_total_steps is None or steps_here < self.max_total_steps):
            if self.before_step is not None:
                self.before_step()
            active, self.stopped_now = self.active, False
            t0, c0 = time.perf_counter(), time.process_time()
            td.set("action", agent.act(td))
            td, td_next = env.step_and_maybe_reset(td)
            agent.observe(td, active)
            dt, dc = time.perf_counter() - t0, time.process_time() - c0
            if self.time_steps:
                self.step_seconds.append(dt)
            self.total += 1
            steps_here += 1
            nxt = td.get("next")
            r = nxt.get("reward").reshape(S).to(torch.float64)
            self._check_finite(r, nxt.get("observation"), active)
            n_active = int(active.sum())
            self.steps += active
            self.env_steps_done += active
            self.ret += torch.where(active, r, 0.0)
            self.wall += active.to(self.wall.dtype) * (dt / n_active)   # float64: a bool mask times a float is float32
            self.cpu += active.to(self.cpu.dtype) * (dc / n_active)
            ended = nxt.get("done").reshape(S) & active
            new_rows = []
            if ended.any():
                new_rows = self._finish(ended, nxt)
                if keep:
                    rows += new_rows
                if not budget:
                    bar.update(len(new_rows))
            if budget and self.progress and self.total % 50 == 0:
                bar.update(self._progress() - bar.n)
            td = self.td = td_next
            if new_rows and on_rows is not None:
                on_rows(new_rows)
            if after_step is not None and after_step(self):
                break
        if budget and self.progress:
            bar.update(self._progress() - bar.n)
        bar.close()
        return frame(rows)

    def _progress(self) -> int:
        """Seed-episodes done, or with a budget the seeds' environment steps (each up to it)."""
        if self.env_steps:
            return int(self.env_steps_done.clamp(max=self.env_steps).sum())
        return self.episodes_done

    def _check_finite(self, reward, obs, active) -> None:
        """A NaN or inf from the env stops the run here, naming where (it would otherwise
        poison the learner silently)."""
        bad = ~torch.isfinite(reward)
        if obs.is_floating_point():
            bad |= ~torch.isfinite(obs.reshape(len(reward), -1)).all(-1)
        bad &= active
        if bad.any():
            i = int(bad.nonzero()[0, 0])
            what = "reward" if not torch.isfinite(reward[i]) else "observation"
            raise NonFiniteError(f"the env returned a non-finite {what} for seed {self.seeds[i]}, episode "
                                 f"{int(self.episode[i]) + 1}, step {int(self.steps[i]) + 1}")

    def _finish(self, ended: torch.Tensor, nxt) -> List[dict]:
        """Rows of the episodes that just ended (``nxt``: the step's "next" entries, before
        any reset); reset their accumulators."""
        self.episode += ended
        S = len(self.seeds)
        terminated = nxt.get("terminated").reshape(S)
        stats = {k: nxt.get(k).reshape(S).tolist() for k in getattr(self.env, "episode_info", ())}
        stats.update({k: v.tolist() for k, v in self.agent.episode_stats().items()})
        rows = []
        for i in ended.nonzero()[:, 0].tolist():
            steps = int(self.steps[i])
            rows.append(dict(seed=self.seeds[i], episode=int(self.episode[i]), steps=steps,
                             **{"return": float(self.ret[i])}, terminated=bool(terminated[i]),
                             wall_s=float(self.wall[i]), cpu_s=float(self.cpu[i]),
                             us_per_step=float(self.wall[i]) / steps * 1e6,
                             **{k: v[i] for k, v in stats.items()}))
        for name in ("steps", "ret", "wall", "cpu"):
            getattr(self, name)[ended] = 0
        was_active = self.active.clone()
        self.active &= self.episode < self.episodes
        if self.env_steps:  # only at the end of a seed's own episode
            self.active &= ~(ended & (self.env_steps_done >= self.env_steps))
        stopped = was_active & ~self.active
        self.stopped_at[stopped] = self.total
        self.stopped_now = bool(stopped.any())
        return rows

    @property
    def first_stop(self) -> bool:
        """Seeds stopped in the step just taken, and none before (-2: at a step unknown): the
        state from which every stopped seed can be continued exactly. (A seed that stays
        stopped when a run is lengthened keeps this state the one to continue from.)"""
        if not self.stopped_now:  # (checked after every step: the tensors only when a seed stopped)
            return False
        return not bool(((self.stopped_at != -1) & (self.stopped_at < self.total)).any())

    def to_continue(self) -> torch.Tensor:
        """Stopped seeds that ``episodes`` and ``env_steps`` (lengthened since) say go on."""
        more = ~self.active & (self.episode < self.episodes)
        if self.env_steps:
            more &= self.env_steps_done < self.env_steps
        return more

    def reactivate(self) -> None:
        """Let the seeds of ``to_continue`` go on; ValueError if any of them has been
        stepped since it stopped (this state cannot continue it exactly)."""
        more = self.to_continue()
        late = more & (self.stopped_at != self.total)
        if late.any():
            raise ValueError(f"seeds {[self.seeds[i] for i in late.nonzero()[:, 0].tolist()]} stopped at an "
                             f"earlier step than this state's {self.total}")
        if more.any():
            self.active |= more
            self.stopped_at[more] = -1

    def state_dict(self) -> dict:
        return {"total": self.total, "td": None if self.td is None else self.td.to_dict(),
                **{name: getattr(self, name).clone() for name in self.ACCUMULATORS}}

    def load_state_dict(self, state: dict) -> None:
        # what older checkpoints lack: no budget yet; where seeds stopped unknown (-2: cannot be continued)
        state = {"env_steps_done": torch.zeros_like(self.steps),
                 "stopped_at": torch.where(state["active"], -1, -2), **state}
        for name in self.ACCUMULATORS:
            if state[name].shape != getattr(self, name).shape:
                raise ValueError(f"collector state is for {state[name].shape[0]} seeds, not {len(self.seeds)}")
            getattr(self, name).copy_(state[name])
        self.total = int(state["total"])
        self.td = (None if state["td"] is None else
                   TensorDict(state["td"], batch_size=self.env.batch_size, device=self.env.device))


def frame(rows: List[dict]) -> pd.DataFrame:
    """Rows as a DataFrame with the fixed columns first, sorted by seed and episode."""
    extra = [c for c in (rows[0] if rows else {}) if c not in COLUMNS]
    df = pd.DataFrame(rows, columns=COLUMNS + extra)
    return df.sort_values(["seed", "episode"], kind="stable").reset_index(drop=True)
