"""The study itself: ``Study`` joins its parts, and ``work`` / ``worker`` fill it."""
from __future__ import annotations

import sys
from pathlib import Path

from trl_dgpq.analysis.objective import at_budget_objective, objective, worst_objective
from trl_dgpq.collectors.experiment import classes, split_overrides
from trl_dgpq.config import find_leaf, from_dict
from trl_dgpq.tuning import Factors, parse_range, search_space, with_ranges

from .config import TuneConfig, stage_lengths
from .preset import Preset
from .signals import Stopped, stop_on_signals
from .staging import Staging
from .storage import Storage, quiet_optuna
from .trials import Trials
from .validation import Validation


class Study(Storage, Trials, Staging, Validation, Preset):
    """The study in ``out`` (storage ``url``): what it was asked (``request``: the settings given,
    the full-budget config, the TuneConfig) and the Optuna study over it."""

    def __init__(self, out, url: str, request: dict):
        self.out, self.url, self.request = Path(out), url, request
        self.name = self.out.resolve().name
        self.tune = from_dict(TuneConfig, request["tune"])
        self.config = request["config"]
        self.stages = stage_lengths(self.config["run"], self.tune.stages)
        self.objective = objective(self.config["run"]["env"], self.tune.objective, self.tune.window, self.stages,
                                   self.tune.measure)
        # the column its trials were scored on, kept: were the env's measure to change, new trials
        # would otherwise be scored on another scale than the old ones and compared with them
        scored = request.setdefault("scored", self.objective.column)
        if scored != self.objective.column:
            args = (scored, scored, self.objective.direction, self.tune.window)
            note = "; the env's measure when the study began"
            self.objective = (worst_objective(*args, self.stages, note) if self.tune.objective == "worst"
                              else at_budget_objective(*args, note))
        agent_cls = classes(self.config["run"])[1]
        given = split_overrides(self.given_agent_env(), *classes(self.config["run"]))
        weights = {name: self.value_of("agent", name) for name, _ in map(parse_range, self.tune.search)
                   if find_leaf(agent_cls.Config, name) is not None}
        space = with_ranges(search_space(agent_cls), self.tune.search, weights)
        # a setting given on the command line is kept, not searched; given weights are the base its Factors scale
        self.space = {k: r for k, r in space.items()
                      if find_leaf(agent_cls.Config, k).key not in given["agent"] or isinstance(r, Factors)}
        if not self.space:
            raise ValueError("every setting of the search space is given on the command line: nothing to tune")

    def given_agent_env(self) -> dict:
        """The settings given on the command line, but the run's."""
        from trl_dgpq.collectors.experiment import run_settings
        run = run_settings(self.request["given"])
        return {k: v for k, v in self.request["given"].items() if k.removeprefix("run.") not in run}


def work(study: Study, trials: int, stop: dict, log=print) -> None:
    """Run trials until the study holds ``trials`` (Stopped by a signal)."""
    quiet_optuna()
    while (trial := study.next_trial(trials, stop)) is not None:
        study.run(trial, stop, log)


def worker(out: str, url: str, request: dict, trials: int) -> None:
    """A worker process (``--workers``): exit 0 when the study is full, 128 + signal if stopped."""
    from trl_dgpq.collectors.experiment import quiet_torchrl
    quiet_torchrl()
    with stop_on_signals() as stop:
        try:
            work(Study(out, url, request), trials, stop, log=lambda line: print(line, flush=True))
        except Stopped as err:
            sys.exit(128 + err.signum)
