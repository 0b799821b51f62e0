"""What a study is asked: ``TuneConfig``, the stages of its budget, and how settings are shown."""
from __future__ import annotations

import json
import math
import socket
from dataclasses import dataclass
from typing import Tuple

from trl_dgpq.collectors import runner
from trl_dgpq.config import setting
from trl_dgpq.tuning import TUNING_SEEDS, VALIDATION_SEEDS, parse_range

HOST = socket.gethostname()
KEEP = (runner.CONFIG, runner.STATUS, runner.EPISODES)  # what an ended trial's folder keeps
DEFAULT_SEEDS = f"{TUNING_SEEDS.start}-{TUNING_SEEDS.stop - 1}"
DEFAULT_VALIDATION_SEEDS = f"{VALIDATION_SEEDS.start}-{VALIDATION_SEEDS.stop - 1}"
UNMARKED_S = 60  # a running trial without its process's mark this long after it started: that process is gone


@dataclass
class TuneConfig:
    """The study."""
    trials: int = setting(20, "trials the study is to hold; ended ones count (complete, pruned or failed), so a "
                              "larger number run again adds trials", within="[1, inf)")
    workers: int = setting(1, "processes filling the study at once on this machine, a trial each", within="[1, inf)")
    sampler_seed: int = setting(0, "TPE sampler seed (each trial's: this seed and the trial's number)",
                                within="[0, inf)")
    stages: Tuple[float, ...] = setting((0.25, 0.5, 0.75, 1.0), "fractions of the budget after which a trial "
                                        "reports its objective to the pruner (the last is 1)", within="(0, 1]",
                                        length=(1, None))
    prune_after: int = setting(5, "trials that must have ended before MedianPruner stops any "
                                  "(its n_startup_trials)", within="[0, inf)")
    objective: str = setting("report", "what a trial is scored by: 'report', what report.py shows (steps to the "
                                       "domain's threshold where it has one, else its measure at the budget), "
                                       "'measure', the measure at the budget even where there is a threshold (a "
                                       "threshold few trials meet scores them all alike: the budget), or 'worst', "
                                       "the worst of the measure at the ends of the stages after the first (a "
                                       "learner that stays good: --stages 0.2,0.3,...,1 --window 500 of 5,000 "
                                       "episodes scores the worst block of 500 after the first 1,000)",
                             choices=("report", "measure", "worst"))
    window: int = setting(10, "episodes at the end of a trial's budget that the measure is averaged over (a "
                              "domain without a threshold, --objective measure or --measure): more scores how a learner "
                              "ends rather than a lucky stretch", within="[1, inf)")
    measure: str = setting("", "the episodes.csv column trials are scored by, one of the domain's measures "
                               "(default: its own, what report.py shows); a named one is scored at the "
                               "budget (or by --objective worst), never by a threshold, e.g. liquidation's "
                               "noise_free_cost_ratio: the expected cost of the trades played, without the "
                               "price noise that moves its cost_ratio from block to block")
    first: str = setting("preset", "the study's first trial: 'preset', the base preset's own values of the searched "
                                   "settings (those inside their ranges), or 'sampled', as TPE draws it",
                         choices=("preset", "sampled"))
    search: Tuple[str, ...] = setting((), "ranges that replace the agent's own, NAME=LOW:HIGH (log-uniform), comma-"
                                          "separated, e.g. lengthscale=1:30,eps1=0.1:3: for a domain whose metric "
                                          "or reward has another scale than the agent's search space assumes; "
                                          "state_scale=0.25:4 searches each nonzero weight of the base preset's "
                                          "metric times its own factor in that range")

    FIXED = ("sampler_seed", "stages", "prune_after", "objective", "search", "window", "first", "measure")  # kept by the study from its first run

    def cross_check(self) -> None:
        if list(self.stages) != sorted(set(self.stages)) or self.stages[-1] != 1:
            raise ValueError(f"stages must increase and end at 1, got {list(self.stages)}")
        if self.objective == "worst" and len(self.stages) < 2:
            raise ValueError("objective 'worst' scores the stages after the first: give at least two stages")
        for text in self.search:
            parse_range(text)


def stage_lengths(run: dict, fractions) -> list:
    """[{"episodes", "env_steps"}] of each stage of ``run``'s budget (the last: the budget); with a
    budget of env steps the episode cap follows it unless it was given apart."""
    out = []
    for f in fractions:
        if run["env_steps"]:
            steps = max(1, math.ceil(round(f * run["env_steps"], 9)))
            lengths = dict(episodes=steps if run["episodes"] == run["env_steps"] else run["episodes"],
                           env_steps=steps)
        else:
            lengths = dict(episodes=max(1, math.ceil(round(f * run["episodes"], 9))), env_steps=0)
        if not out or lengths != out[-1]:
            out.append(lengths)
    return out


def plain(value):
    """JSON's form of a setting's value (tuples as lists)."""
    return json.loads(json.dumps(value))


def shown(settings: dict) -> str:
    """"lr=0.00123, hidden=64,64"."""
    def text(v):
        return ",".join(map(text, v)) if isinstance(v, (list, tuple)) else f"{v:.4g}" if isinstance(v, float) else str(v)
    return ", ".join(f"{k}={text(v)}" for k, v in settings.items())
