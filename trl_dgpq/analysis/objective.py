"""What a study (``trl-dgpq tune``) optimises: the number ``report.py`` puts in its table for
the domain, per seed, and its interquartile mean over the tuning seeds.

- A domain (or gym id) with a threshold: the env steps a seed took to meet it within the
  budget, a seed that never met it counting as the budget (censored, as the report's IQM
  counts it); fewer is better.
- Otherwise the domain's measure at the budget: each seed's mean over its last ``WINDOW``
  episodes within the budget, in the domain's direction (``MEASURE_LOWER_IS_BETTER``; the
  return by default, more is better).

The budget is the report's for one run (``default_budget``): its ``env_steps``, or for a run
budgeted in episodes the fewest steps any of its seeds ran. The IQM (rliable's, as the
report's) rather than the median: it uses half the seeds, not one or two, and is as robust
to one seed's luck.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

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

    def per_seed(self, run: Run) -> pd.Series:
        budget = default_budget([(None, run)])
        run.need(self.column)
        if self.threshold is not None:
            return steps_to_threshold(run.df, self.threshold, budget).fillna(budget)
        return at_budget(run.df, self.column, budget, self.window)

    def value(self, run: Run) -> float:
        """The IQM over seeds of ``per_seed`` (NaN if no seed has a value: none ended an episode
        within the budget)."""
        return iqm_point(self.per_seed(run))


def objective(env: str, kind: str = "report", window: int = WINDOW) -> Objective:
    """``env``'s objective: ``kind`` "report" as the module says, "measure" the measure at the
    budget even where the domain has a threshold; the measure averaged over each seed's last
    ``window`` episodes (more: a study that scores how a learner ends, not one lucky stretch)."""
    from trl_dgpq.envs import domain, split_name
    d, env_id = domain(env), split_name(env)[1]
    if kind not in ("report", "measure"):
        raise ValueError(f"objective must be 'report' or 'measure', got {kind!r}")
    threshold = d.threshold(env_id) if kind == "report" else None
    if threshold is not None:
        return Objective("steps to threshold", f"steps to threshold ({threshold.text}; a seed that never met it: "
                         "the budget), IQM over seeds", "minimize", threshold, threshold.column)
    column, label = d.measure(env_id)
    return at_budget_objective(column, label, "minimize" if d.lower_is_better(env_id) else "maximize", window)


def at_budget_objective(column: str, label: str, direction: str, window: int, note: str = "") -> Objective:
    """``column`` at the budget: each seed's mean over its last ``window`` episodes, IQM over
    seeds (``note``: said after the window, e.g. why this column)."""
    return Objective(f"{label} at budget", f"{label} at budget (mean of each seed's last {window} episodes{note}), "
                     "IQM over seeds", direction, None, column, window)


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
