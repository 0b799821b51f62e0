"""A study's trials: which count, the next one a process takes, and those whose process is gone
(retried: their parameters enqueued again, their folder handed on)."""
from __future__ import annotations

import os
import signal
from datetime import datetime
from pathlib import Path

from trl_dgpq.collectors import runner

from .config import HOST, UNMARKED_S
from .signals import held


class Trials:
    """Trial bookkeeping (a mixin of ``Study``)."""

    @staticmethod
    def ended(trials) -> dict:
        """{state: trials} of those that count: complete, pruned, failed in their own code."""
        from optuna.trial import TrialState
        out = {"complete": [], "pruned": [], "failed": []}
        for t in trials:
            if t.state == TrialState.COMPLETE:
                out["complete"].append(t)
            elif t.state == TrialState.PRUNED:
                out["pruned"].append(t)
            elif t.state == TrialState.FAIL and "retried" not in t.user_attrs:
                out["failed"].append(t)
        return out

    def done(self, study) -> int:
        return sum(map(len, self.ended(study.get_trials(deepcopy=False)).values()))

    def next_trial(self, trials: int, stop: dict):
        """A new (or retried) trial of this process, or None once the study holds ``trials`` ended
        or running ones."""
        from optuna.trial import TrialState
        trial = None
        with held(stop), self.lock():
            study = self.load()
            self.recover(study)
            running = sum(t.state == TrialState.RUNNING for t in study.get_trials(deepcopy=False))
            if self.done(study) + running < trials:
                trial = study.ask()
                trial.set_user_attr("host", HOST)
                trial.set_user_attr("pid", os.getpid())
                if stop["signum"] is not None:  # it came while the trial was being asked for: hand it on
                    self.retry(study, trial, f"interrupted by {signal.Signals(stop['signum']).name}")
        return trial

    def recover(self, study) -> None:
        """Trials left running by a process of this machine that is gone, or by one killed between
        asking for a trial and marking it (its marks come within milliseconds): failed and retried."""
        from optuna.trial import TrialState
        for t in study.get_trials(deepcopy=False, states=(TrialState.RUNNING,)):
            host, pid = t.user_attrs.get("host"), t.user_attrs.get("pid")
            if host == HOST and not runner._alive(pid):
                self.retry(study, t, f"process {pid} is gone")
            elif host is None and (datetime.now() - t.datetime_start).total_seconds() > UNMARKED_S:
                self.retry(study, t, "its process never marked it")

    def retry(self, study, trial, reason: str) -> None:
        """Fail ``trial`` (running), marked ``retried``, and enqueue its parameters (those it was
        given, if it was stopped before drawing them) as ``retry_of`` the trial whose folder it has
        (the base preset's trial stays marked ``first``)."""
        from optuna.trial import TrialState
        trial = study._storage.get_trial(trial._trial_id)  # (a live trial, too: its stored record)
        params = {**trial.system_attrs.get("fixed_params", {}), **trial.params}
        owner = trial.number if self.folder(trial.number).exists() else trial.user_attrs.get("retry_of", trial.number)
        study._storage.set_trial_user_attr(trial._trial_id, "retried", reason)
        study._storage.set_trial_state_values(trial._trial_id, TrialState.FAIL)
        first = {"first": trial.user_attrs["first"]} if "first" in trial.user_attrs else {}  # validate reruns it
        study.enqueue_trial(params, user_attrs={"retry_of": owner, **first})

    def folder(self, number: int) -> Path:
        return self.out / "trials" / f"{number:04d}"
