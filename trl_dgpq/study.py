"""A study (``trl-dgpq tune``): Optuna trials of one agent on one env, every trial an ordinary
run with the same budget, seeds and settings but for the agent's ``SEARCH_SPACE``.

    DIR/study.db        Optuna's storage, sqlite:///DIR/study.db (or any URL given instead)
    DIR/study.lock      held while a process on this machine picks its next trial
    DIR/trials/NNNN/    trial NNNN's run folder; once it has ended, only config.json,
                        status.json and episodes.csv (its checkpoints are what resume needs)
    DIR/validation/NNNN/  trial NNNN run again on the validation seeds (``validate``)

A trial runs in stages (``stages``: fractions of the budget), lengthened between them with
the runner's exact ``lengthen``, so after the last it is the run asked for that budget from
the start. After each stage it reports the objective of what it has run so far (the rows a
run of that length has: ``analysis.objective.stage``) and MedianPruner may stop it there.

A trial whose process stops (Ctrl-C, SIGTERM, a crash, kill -9) is marked failed and its
parameters enqueued again, marked ``retry_of``: the trial that takes them renames the old
trial's folder to its own and goes on from its checkpoint (``runner.resume``), so nothing
run is lost. A stopped process does this itself; a killed one's trials are found by the
next process on the same machine that picks a trial (their pid is gone). Trials count
towards ``trials`` once ended: complete, pruned or failed in their own code (an exception,
recorded as ``error``), not those handed on to a retry.
"""
from __future__ import annotations

import functools
import json
import math
import os
import signal
import socket
import sys
import time
import warnings
from contextlib import contextmanager
from dataclasses import dataclass
from datetime import datetime
from pathlib import Path
from typing import Optional, Tuple

import numpy as np

from trl_dgpq.analysis.objective import at_budget_objective, covers, objective, stage, worst_objective
from trl_dgpq.analysis.runs import load_run
from trl_dgpq.collectors import runner
from trl_dgpq.collectors.experiment import classes, resolve_config, split_overrides
from trl_dgpq.config import find_leaf, from_dict, setting, to_dict
from trl_dgpq.presets import check_preset_name, preset_overrides, tuned_name, write_tuned
from trl_dgpq.selection import check_selection_seeds
from trl_dgpq.tuning import (TUNING_SEEDS, VALIDATION_SEEDS, Factors, check_tuning_seeds, first_params, parse_range,
                             search_space, suggest, with_ranges)

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


class Stopped(Exception):
    """SIGINT or SIGTERM arrived outside a run (inside one, the runner checkpoints first)."""

    def __init__(self, signum: int):
        self.signum = signum
        super().__init__(f"interrupted by {signal.Signals(signum).name}")


@contextmanager
def stop_on_signals():
    """SIGINT / SIGTERM raise Stopped: the first one, at once unless ``held``; later ones are
    ignored while stopping. Yields the state, whose "signum" a caller sets when the runner
    caught the signal instead (a run checkpoints before it stops)."""
    state = {"signum": None, "held": False}

    def handler(signum, frame):
        if state["signum"] is None:
            state["signum"] = signum
            if not state["held"]:
                raise Stopped(signum)
    previous = {s: signal.signal(s, handler) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield state
    finally:
        for s, h in previous.items():
            signal.signal(s, h)


@contextmanager
def held(stop: dict):
    """A signal waits for the end of the block (the study's records of a trial are written whole:
    a trial asked for is always marked with its process), then raises Stopped."""
    stop["held"] = True
    try:
        yield
    finally:
        stop["held"] = False
    if stop["signum"] is not None:
        raise Stopped(stop["signum"])


def storage_url(out, storage: Optional[str] = None) -> str:
    return storage or f"sqlite:///{Path(out).resolve() / 'study.db'}"


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


class Study:
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

    # ------------------------------------------------------------ opening
    @classmethod
    def open(cls, out, storage: Optional[str], given: dict, tune_given: dict) -> "Study":
        """The study in ``out``: created from ``given`` (settings as on train's command line) and
        ``tune_given`` (TuneConfig settings), or reopened, refusing settings that differ from its own
        (ValueError, one line)."""
        import optuna
        quiet_optuna()
        url, name = storage_url(out, storage), Path(out).resolve().name
        stored = cls.stored_request(url, name)
        if stored is not None:
            request = cls.reopen_request(stored, given, tune_given)
        else:
            given = {"seeds": DEFAULT_SEEDS, **given}
            request = dict(given=given, config=resolve_config(given), tune=to_dict(from_dict(TuneConfig, tune_given)))
        check_tuning_seeds(request["config"]["run"]["seeds"])
        study = cls(out, url, request)
        Path(out).mkdir(parents=True, exist_ok=True)  # only once all is checked
        created = optuna.create_study(study_name=name, storage=open_storage(url), load_if_exists=True,
                                      direction=study.objective.direction)
        created.set_user_attr("request", request)
        if stored is None and study.tune.first == "preset":
            study.enqueue_preset(created)
        return study

    def enqueue_preset(self, study) -> None:
        """The study's first trial runs the base preset's own values of the searched settings
        (those inside their ranges): a study whose sampled trials all miss (a threshold none
        meets scores them alike) still holds the setting it started from, and TPE its place."""
        values = {k: self.value_of("agent", k) for k in self.space}
        params = first_params(self.space, values, self.config["run"]["env_steps"])
        if params:
            study.enqueue_trial(params, user_attrs={"first": f"preset {self.config['run']['preset']}"})

    @staticmethod
    def stored_request(url: str, name: str) -> Optional[dict]:
        """The request of the study ``name`` at ``url`` (None if there is none; a SQLite file that
        does not exist is not created)."""
        import optuna
        if url.startswith("sqlite:///") and not Path(url.removeprefix("sqlite:///")).exists():
            return None
        if name not in optuna.study.get_all_study_names(open_storage(url)):
            return None
        return optuna.load_study(study_name=name, storage=open_storage(url)).user_attrs.get("request")

    @staticmethod
    def reopen_request(stored: dict, given: dict, tune_given: dict) -> dict:
        """The stored request, its trials and workers updated from ``tune_given``; ValueError if
        ``given`` (over the stored settings) or the fixed TuneConfig settings ask for another study."""
        tune = to_dict(from_dict(TuneConfig, {**stored["tune"], **tune_given}))
        kept = to_dict(from_dict(TuneConfig, stored["tune"]))  # a study made before a setting existed: its default
        for key in TuneConfig.FIXED:
            if tune[key] != kept[key]:
                raise ValueError(f"the study keeps its {key} {kept[key]}: continue it without "
                                 f"--{key.replace('_', '-')}")
        if given:
            config = resolve_config({**stored["given"], **given})
            differ = [f"{section}.{k}" for section in ("run", "env", "agent") for k in
                      sorted(set(config[section]) | set(stored["config"][section]))
                      if config[section].get(k) != stored["config"][section].get(k)]
            if differ:
                raise ValueError(f"the study was made with other settings ({', '.join(differ)} differ): continue it "
                                 "with the same settings, or none (--trials and --workers may change)")
        return dict(stored, tune=tune)

    def given_agent_env(self) -> dict:
        """The settings given on the command line, but the run's."""
        from trl_dgpq.collectors.experiment import run_settings
        run = run_settings(self.request["given"])
        return {k: v for k, v in self.request["given"].items() if k.removeprefix("run.") not in run}

    def load(self):
        """The Optuna study, with the MedianPruner and a TPE sampler seeded by the study's seed and
        its next trial's number: the same suggestions however many processes fill it, or restarts."""
        import optuna
        pruner = optuna.pruners.MedianPruner(n_startup_trials=self.tune.prune_after)
        study = optuna.load_study(study_name=self.name, storage=open_storage(self.url), pruner=pruner)
        n = len(study.get_trials(deepcopy=False))
        seed = int(np.random.SeedSequence([self.tune.sampler_seed, n]).generate_state(1)[0])
        study.sampler = optuna.samplers.TPESampler(seed=seed)
        return study

    @contextmanager
    def lock(self):
        """One process of this machine at a time picks a trial (and fails those of dead processes)."""
        import fcntl
        with open(self.out / "study.lock", "a") as f:
            fcntl.flock(f, fcntl.LOCK_EX)
            try:
                yield
            finally:
                fcntl.flock(f, fcntl.LOCK_UN)

    # ------------------------------------------------------------ counting
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

    # ------------------------------------------------------------ trials
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
        with held(stop):
            if pruned is not None:
                study.tell(trial, state=TrialState.PRUNED)
                log(f"trial {trial.number}: pruned {pruned}")
            elif error is not None:
                trial.set_user_attr("error", error)
                study.tell(trial, state=TrialState.FAIL)
                log(f"trial {trial.number}: failed: {error}")
            else:
                study.tell(trial, value)
                log(f"trial {trial.number}: {self.objective.name} {value:.6g} with "
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

    # ------------------------------------------------------------ validation
    def validate(self, k: int, seeds, log=print) -> dict:
        """Run the ``k`` best complete trials, and the first (the base preset's) if it completed,
        again at the full budget on ``seeds``, other tuning seeds than the study's: the best of
        30 trials on 5 seeds is partly the luckiest (on CartPole DGPQ's best trial beat the
        preset by 10 % on the tuning seeds and lost to it by half on 10 others). Each value is
        kept in the study (user attr ``validation``, by trial number), and a run stopped midway
        goes on from its checkpoint when asked again. Returns {trial number: value}."""
        from optuna.trial import TrialState
        from trl_dgpq.analysis.results import seeds_text
        seeds = self.validation_seeds(seeds)
        study = self.load()
        done = [t for t in study.get_trials(deepcopy=False) if t.state == TrialState.COMPLETE]
        if not done:
            raise ValueError("no trial has completed: there is nothing to validate")
        ranked = sorted(done, key=lambda t: t.value, reverse=self.objective.direction == "maximize")
        picked = ranked[:k] + [t for t in ranked[k:] if "first" in t.user_attrs]
        stored = study.user_attrs.get("validation", {})
        # values on other seeds do not compare with these: start over
        results = {int(n): v for n, v in stored.get("values", {}).items()} if stored.get("seeds") == seeds else {}
        for t in picked:
            if t.number not in results:
                path = self.out / "validation" / f"{t.number:04d}"
                config = resolve_config({**self.request["given"], "seeds": seeds_text(seeds),
                                         **{f"agent.{k}": v for k, v in t.user_attrs["settings"].items()}})
                self.run_to_end(path, config)
                results[t.number] = self.objective.value(stage(load_run(path), self.stages[-1]))
                self.tidy(path)
                study.set_user_attr("validation", dict(seeds=seeds, values={str(n): v for n, v in results.items()}))
            log(f"trial {t.number}: {self.objective.name} {results[t.number]:.6g} on the validation seeds "
                f"{seeds_text(seeds)} ({t.value:.6g} on the tuning seeds{', the base preset' if 'first' in t.user_attrs else ''})")
        return results

    def validation_seeds(self, seeds) -> list:
        """``seeds`` sorted, once checked: no reporting seed, none of the study's own (ValueError)."""
        seeds = sorted(set(seeds))
        check_selection_seeds(seeds, "validation seeds", DEFAULT_VALIDATION_SEEDS)
        own = self.config["run"]["seeds"]
        shared = sorted(set(seeds) & set(own))
        if shared:
            raise ValueError(f"validation seeds {shared} are the study's own tuning seeds: validate on others, e.g. "
                             f"--validation-seeds {max(own) + 1}-{max(own) + 10}")
        return seeds

    @staticmethod
    def run_to_end(path: Path, config: dict) -> None:
        """``config``'s run in ``path``: started, or resumed from its checkpoint, to its end."""
        recorded = runner.RunFolder(path).read_json(runner.CONFIG) if (path / runner.CONFIG).exists() else None
        if recorded is None or any(recorded[k] != config[k] for k in ("run", "env", "agent")):
            folder = runner.RunFolder.create(str(path), "", overwrite=True)  # held
            try:
                runner.start(config, folder, progress=False)
            finally:
                folder.release()
            return
        folder = runner.RunFolder.existing(path)
        if not folder.finished():
            folder.acquire()
            try:
                runner.resume(folder, runner.resumable_config(folder), progress=False)
            finally:
                folder.release()

    def best_trial(self, study):
        """The trial a preset is written from: the best on the validation seeds where trials were
        validated (with its value there), else the best on the tuning seeds (value None)."""
        validation = study.user_attrs.get("validation", {}).get("values", {})
        if not validation:
            return study.best_trial, None
        pick = (max if self.objective.direction == "maximize" else min)(validation, key=lambda n: validation[n])
        return study.trials[int(pick)], validation[pick]

    # ------------------------------------------------------------ results
    def summary(self, trials: int) -> str:
        """One line: the best trial, its objective and settings, and how many trials have ended."""
        study = self.load()
        ended = self.ended(study.get_trials(deepcopy=False))
        done = sum(map(len, ended.values()))
        tally = (f"{done}/{trials} trials done ({len(ended['complete'])} complete, {len(ended['pruned'])} pruned, "
                 f"{len(ended['failed'])} failed)")
        if not ended["complete"]:
            return f"no trial has completed; {tally}"
        best = study.best_trial
        seeds = self.config["run"]["seeds"]
        better = "lower" if self.objective.direction == "minimize" else "higher"
        return (f"best: trial {best.number}, {self.objective.name} {best.value:.6g} ({better} is better, IQM over "
                f"{len(seeds)} seeds) with {shown(best.user_attrs['settings'])}; {tally}")

    def replaces(self, name: str) -> Optional[str]:
        """What writing preset ``name`` would replace, in words, if another study wrote it (None: no
        preset of that name, or one this study wrote)."""
        from trl_dgpq.presets import tuned_entries
        run = self.config["run"]
        old = (tuned_entries(run["env"]).get(run["agent"]) or {}).get(name)
        prov = (old or {}).get("provenance") or {}
        if old is None or prov.get("study_name") == self.name:
            return None
        return (f"preset {name!r} of {run['agent']} on {run['env']}, written by study {prov.get('study_name', '?')!r} "
                f"({prov.get('trials', '?')} trials on seeds {prov.get('seeds', '?')}, {prov.get('date', '?')})")

    def write_preset(self, name: Optional[str] = None, force: bool = False) -> Tuple[str, Path]:
        """The best trial as preset ``name`` of this env and agent (by default ``tuned``, or
        ``<preset>-tuned`` if the study ran on another than the env's default): the preset the
        study ran on, the settings given to it and the trial's over it, with where it came from.
        A preset another study wrote is replaced only with ``force`` (ValueError saying what it
        is otherwise). Returns the name and the file written."""
        from trl_dgpq.collectors.runner import provenance
        run = self.config["run"]
        name = name or tuned_name(run["env"], run["preset"])
        check_preset_name(run["env"], run["agent"], name)
        other = self.replaces(name)
        if other and not force:
            raise ValueError(f"this study would replace {other}: write it under another name (--write-preset NAME), "
                             "or add --force to replace it")
        study = self.load()
        ended = self.ended(study.get_trials(deepcopy=False))
        if not ended["complete"]:
            raise ValueError("no trial has completed: there is no best trial to write as a preset")
        best, validated = self.best_trial(study)
        _, base = preset_overrides(run["env"], run["agent"], run["preset"])
        given = split_overrides(self.given_agent_env(), *classes(run))
        sections = {s: {**base[s], **{k: self.value_of(s, k) for k in given[s]}} for s in ("env", "agent")}
        sections["agent"].update(best.user_attrs["settings"])
        return name, write_tuned(run["env"], run["agent"], name, sections, dict(
            study=portable(self.url), study_name=self.name, trial=best.number, trials=sum(map(len, ended.values())),
            objective=self.objective.name, window=self.tune.window, direction=self.objective.direction,
            value=best.value,
            base_preset=run["preset"], budget=dict(episodes=run["episodes"], env_steps=run["env_steps"]),
            seeds=run["seeds"], date=time.strftime("%Y-%m-%d %H:%M:%S"), commit=provenance()["git"]["commit"],
            **({"search": list(self.tune.search)} if self.tune.search else {}),
            **({"validation": dict(seeds=study.user_attrs["validation"]["seeds"], value=validated,
                                   trials=sorted(map(int, study.user_attrs["validation"]["values"])))}
               if validated is not None else {})))

    def value_of(self, section: str, key: str):
        """A given setting's value as the study's config resolved it."""
        cls = {"env": classes(self.config["run"])[0].Config, "agent": classes(self.config["run"])[1].Config}[section]
        node = self.config[section]
        for p in find_leaf(cls, key).path:
            node = node[p]
        return node


def portable(url: str) -> str:
    """A study's storage as provenance records it: a SQLite file under this checkout relative to it
    (an absolute path means nothing on another machine); any other URL as given."""
    prefix = "sqlite:///"
    if url.startswith(prefix):
        path = Path(url[len(prefix):])
        root = Path(__file__).resolve().parent.parent
        if path.is_absolute() and path.resolve().is_relative_to(root):
            return prefix + path.resolve().relative_to(root).as_posix()
    return url


@functools.lru_cache(maxsize=None)
def open_storage(url: str):
    """Optuna's RDB storage at ``url``; SQLite waits for a busy file (several workers write it)."""
    import optuna
    kwargs = {"connect_args": {"timeout": 120}} if url.startswith("sqlite") else {}
    return optuna.storages.RDBStorage(url, engine_kwargs=kwargs)


def quiet_optuna() -> None:
    """The command prints a line per trial; Optuna's own INFO lines and experimental-feature
    warnings only repeat or clutter them."""
    import optuna
    optuna.logging.set_verbosity(optuna.logging.WARNING)
    warnings.filterwarnings("ignore", category=optuna.exceptions.ExperimentalWarning)


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


__all__ = ["TuneConfig", "Study", "Stopped", "stop_on_signals", "stage_lengths", "storage_url", "work", "worker"]
