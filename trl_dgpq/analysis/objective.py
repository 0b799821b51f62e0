"""What a study (``trl-dgpq tune``) optimises: the number ``report.py`` puts in its table for
the domain, per seed, and its interquartile mean over the tuning seeds.

- A domain (or gym id) with a threshold: the env steps a seed took to meet it within the
  budget, a seed that never met it counting as the budget (censored, as the report's IQM
  counts it); fewer is better.
- Otherwise the domain's measure at the budget: each seed's mean over its last ``WINDOW``
  episodes within the budget, in the domain's direction (``MEASURE_LOWER_IS_BETTER``; the
  return by default, more is better).
- Or (kind "worst") the worst of that measure at the ends of a study's stages after the
  first: a learner that gets good and stays good, not one good at the end only (issue 28's
  liquidation goal: no block of 500 episodes after the first 1,000 much above the best).

The budget is the report's for one run (``default_budget``): its ``env_steps``, or for a run
budgeted in episodes the fewest steps any of its seeds ran. The IQM (rliable's, as the
report's) rather than the median: it uses half the seeds, not one or two, and is as robust
to one seed's luck.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Optional, Tuple

import pandas as pd

from .report import WINDOW, default_budget
from .runs import Run
from .stats import iqm_point
from .summary import Threshold, at_budget, steps_to_threshold


@dataclass(frozen=True)
class Objective:
    name: str                       # short, for a line per trial
    text: str                       # what it is, in full
    direction: str                  # "minimize" or "maximize", as Optuna says it
    threshold: Optional[Threshold]  # steps to it, or (None) the measure at the budget:
    column: str
    window: int = WINDOW            # the measure's episodes at the end of the budget
    stages: Tuple[Tuple[int, int], ...] = ()  # (episodes, env_steps) ends where "worst" looks (empty: the budget)

    def per_seed(self, run: Run) -> pd.Series:
        if self.stages:
            return self.worst_per_seed(run)
        budget = default_budget([(None, run)])
        run.need(self.column)
        if self.threshold is not None:
            return steps_to_threshold(run.df, self.threshold, budget).fillna(budget)
        return at_budget(run.df, self.column, budget, self.window)

    def worst_per_seed(self, run: Run) -> pd.Series:
        """Per seed, the worst of the measure at each of ``stages`` that ``run`` reaches (NaN
        where it reaches none): a run staged to its k-th end scores the worst so far, so the
        pruner sees a value that can only get worse as the trial goes on. A budget of episodes
        ends each seed at the stage's episode (episodes differ in length: the fewest steps any
        seed ran would cut a seed with short episodes early)."""
        run.need(self.column)
        df = run.df
        seeds = sorted(df["seed"].unique())
        values = []
        for episodes, steps in self.stages:
            if not covers(run.config, dict(episodes=episodes, env_steps=steps)):
                continue
            if steps:
                values.append(at_budget(df, self.column, steps, self.window).reindex(seeds))
            else:
                block = df[(df["episode"] <= episodes) & (df["episode"] > episodes - self.window)]
                values.append(block.groupby("seed")[self.column].mean().reindex(seeds))
        if not values:
            return pd.Series(float("nan"), index=seeds)
        values = pd.concat(values, axis=1)
        return values.max(axis=1) if self.direction == "minimize" else values.min(axis=1)  # of the ends it has

    def value(self, run: Run) -> float:
        """The IQM over seeds of ``per_seed`` (NaN if no seed has a value: none ended an episode
        within the budget)."""
        return iqm_point(self.per_seed(run))


def objective(env: str, kind: str = "report", window: int = WINDOW, stages=(), measure: str = "") -> Objective:
    """``env``'s objective: ``kind`` "report" as the module says, "measure" the measure at the
    budget even where the domain has a threshold, "worst" the worst of the measure at the ends
    of ``stages`` ([{"episodes", "env_steps"}], a study's) after the first; the measure (the
    domain's, or its other one named ``measure``) averaged over each seed's last ``window``
    episodes (more: a study that scores how a learner ends, not one lucky stretch)."""
    from trl_dgpq.envs import domain, split_name
    d, env_id = domain(env), split_name(env)[1]
    if kind not in ("report", "measure", "worst"):
        raise ValueError(f"objective must be 'report', 'measure' or 'worst', got {kind!r}")
    column, label = d.measure(env_id, measure)
    threshold = d.threshold(env_id) if kind == "report" and not measure else None
    if threshold is not None:
        return Objective("steps to threshold", f"steps to threshold ({threshold.text}; a seed that never met it: "
                         "the budget), IQM over seeds", "minimize", threshold, threshold.column)
    direction = "minimize" if d.lower_is_better(env_id) else "maximize"
    if kind == "worst":
        return worst_objective(column, label, direction, window, stages)
    return at_budget_objective(column, label, direction, window)


def worst_objective(column: str, label: str, direction: str, window: int, stages, note: str = "") -> Objective:
    """``column``'s worst at the ends of ``stages`` after the first (each seed's mean over its last
    ``window`` episodes before each end), IQM over seeds."""
    ends = tuple((s["episodes"], s["env_steps"]) for s in stages[1:])
    if not ends:
        raise ValueError("objective 'worst' needs at least two stages: it scores the stages after the first")
    where = ", ".join(f"{e:,}" for e, _ in ends) if not ends[0][1] else ", ".join(f"{s:,} steps" for _, s in ends)
    return Objective(f"worst {label}", f"worst {label} after the first stage (each seed's mean of its last {window} "
                     f"episodes before {where}; the worst of these{note}), IQM over seeds", direction, None, column,
                     window, ends)


def at_budget_objective(column: str, label: str, direction: str, window: int, note: str = "") -> Objective:
    """``column`` at the budget: each seed's mean over its last ``window`` episodes, IQM over
    seeds (``note``: said after the window, e.g. why this column)."""
    return Objective(f"{label} at budget", f"{label} at budget (mean of each seed's last {window} episodes{note}), "
                     "IQM over seeds", direction, None, column, window)


def covers(config: dict, lengths: dict) -> bool:
    """Whether a run of ``config`` is at least as long as ``lengths`` ({"episodes", "env_steps"})."""
    run = config["run"]
    return lengths["episodes"] <= run["episodes"] and (
        not run["env_steps"] or lengths["env_steps"] <= run["env_steps"])


def stage(run: Run, lengths: dict) -> Run:
    """``run`` as a run of ``lengths`` ({"episodes", "env_steps"}) would have been: each seed's
    episodes begun before it had taken ``env_steps`` steps (0: no budget) and within
    ``episodes``. A run lengthened exactly has these rows first, so a longer run holds every
    shorter one."""
    df = run.df
    keep = df["episode"] <= lengths["episodes"]
    if lengths["env_steps"]:
        keep &= df["env_steps"] - df["steps"] < lengths["env_steps"]
    config = {**run.config, "run": {**run.config["run"], **lengths}}
    return Run(run.path, df[keep].reset_index(drop=True), config)
