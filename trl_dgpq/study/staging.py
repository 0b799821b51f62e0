"""A trial's run, stage by stage: lengthened exactly between stages, its objective reported to the
pruner after each; a retried trial goes on from its checkpoint."""
from __future__ import annotations

import math
import os
from pathlib import Path

from trl_dgpq.analysis.objective import covers, stage
from trl_dgpq.analysis.runs import load_run
from trl_dgpq.collectors import runner
from trl_dgpq.collectors.experiment import resolve_config
from trl_dgpq.tuning import suggest

from .config import KEEP, plain, shown
from .signals import Stopped, held


class Staging:
    """Running a trial (a mixin of ``Study``)."""

    def run(self, trial, stop: dict, log) -> None:
        """Run ``trial`` to its end and tell the study; Stopped (after handing the trial to a retry)
        if a signal stops it."""
        import optuna
        from optuna.trial import TrialState
        study, error, pruned = trial.study, None, None
        try:
            value = self.run_stages(trial)
        except optuna.TrialPruned as err:
            pruned = err
        except (Stopped, runner.Interrupted) as err:
            stop["signum"] = stop["signum"] or err.signum  # (the runner caught it) no other stops this
            self.retry(study, trial, str(err))
            raise Stopped(stop["signum"]) from None
        except Exception as err:  # the trial's own failure (a GP's numerical error): recorded, the study goes on
            error = f"{type(err).__name__}: {str(err).splitlines()[0] if str(err) else ''}"
        else:
            if math.isnan(value):
                error = "no seed ended an episode within the budget"
        # a retried trial has a number of its own (Optuna's): say whose run it went on with
        number = trial.number if trial.user_attrs.get("retry_of") is None else \
            f"{trial.number} (the retry of trial {trial.user_attrs['retry_of']}, its run continued)"
        with held(stop):
            if pruned is not None:
                study.tell(trial, state=TrialState.PRUNED)
                log(f"trial {number}: pruned {pruned}")
            elif error is not None:
                trial.set_user_attr("error", error)
                study.tell(trial, state=TrialState.FAIL)
                log(f"trial {number}: failed: {error}")
            else:
                study.tell(trial, value)
                log(f"trial {number}: {self.objective.name} {value:.6g} with "
                    f"{shown(trial.user_attrs['settings'])}")
            self.tidy(self.folder(trial.number))

    def run_stages(self, trial) -> float:
        """The trial's run, stage by stage, reporting each stage's objective; its final objective."""
        import optuna
        path = self.folder(trial.number)
        old = trial.user_attrs.get("retry_of")
        if old is not None and not path.exists() and self.folder(old).exists():
            os.replace(self.folder(old), path)  # the retry goes on where the stopped trial was
        settings = suggest(trial, self.space, self.config["run"]["env_steps"])
        trial.set_user_attr("settings", plain(settings))
        config = resolve_config({**self.request["given"], **{f"agent.{k}": v for k, v in settings.items()}})
        folder, now = self.open_run(trial, path, config)
        try:
            value = math.nan
            for k, lengths in enumerate(self.stages):
                if not covers(now, lengths):
                    folder.acquire()
                    now = runner.lengthen(folder, runner.resumable_config(folder, lengthen=True), **lengths)
                    runner.resume(folder, now, progress=False)
                value = self.objective.value(stage(load_run(path), lengths))
                step = lengths["env_steps"] or lengths["episodes"]
                if math.isnan(value) or k == len(self.stages) - 1:
                    continue
                trial.report(value, step)
                if trial.should_prune():
                    raise optuna.TrialPruned(f"at {step:,} {'env steps' if lengths['env_steps'] else 'episodes'} "
                                             f"({self.objective.name} {value:.6g})")
            return value
        finally:
            folder.release()

    def open_run(self, trial, path: Path, config: dict):
        """(folder, its config now): the trial's run folder brought to the end of its current
        stage; a retried trial's goes on from its checkpoint, a new one starts its first stage."""
        recorded = runner.RunFolder(path).read_json(runner.CONFIG) if (path / runner.CONFIG).exists() else None
        same = recorded is not None and all(recorded[s] == config[s] for s in ("env", "agent"))
        if not same:
            folder = runner.RunFolder.create(str(path), "", overwrite=True)
            first = {**config, "run": {**config["run"], **self.stages[0]}}
            runner.start(first, folder, progress=False)
            return folder, first
        folder = runner.RunFolder.existing(path)
        checkpoint = folder.load_checkpoint()
        trial.set_user_attr("resumed", dict(from_trial=trial.user_attrs.get("retry_of"),
                                            episodes_done=int(checkpoint["episodes_done"]) if checkpoint else 0))
        if folder.finished():
            now = {k: recorded[k] for k in ("run", "env", "agent")}
        else:
            now = runner.resumable_config(folder)
            runner.resume(folder, now, progress=False)
        return folder, now

    @staticmethod
    def tidy(path: Path) -> None:
        """An ended trial keeps its rows and config: no checkpoint (only a resume needs them)."""
        if path.is_dir():
            for p in path.iterdir():
                if p.name not in KEEP and p.is_file():
                    p.unlink()
