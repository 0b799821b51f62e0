"""Where a study lives and how it is made: its storage (SQLite by default, any URL shared by
several machines), its creation and reopening (the request it keeps, the settings it refuses to
change), its direction, sampler and pruner (``load``), and the lock one machine's processes take
to pick a trial."""
from __future__ import annotations

import functools
import warnings
from contextlib import contextmanager
from pathlib import Path
from typing import Optional

import numpy as np

from trl_dgpq.collectors.experiment import resolve_config
from trl_dgpq.config import from_dict, to_dict
from trl_dgpq.tuning import check_tuning_seeds, first_params

from .config import DEFAULT_SEEDS, TuneConfig


def storage_url(out, storage: Optional[str] = None) -> str:
    return storage or f"sqlite:///{Path(out).resolve() / 'study.db'}"


def portable(url: str) -> str:
    """A study's storage as provenance records it: a SQLite file under this checkout relative to it
    (an absolute path means nothing on another machine); any other URL as given."""
    prefix = "sqlite:///"
    if url.startswith(prefix):
        path = Path(url[len(prefix):])
        root = Path(__file__).resolve().parent.parent.parent
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


class Storage:
    """The study's creation and its Optuna study (a mixin of ``Study``)."""

    @classmethod
    def open(cls, out, storage: Optional[str], given: dict, tune_given: dict):
        """The study in ``out``: created from ``given`` (settings as on train's command line) and
        ``tune_given`` (TuneConfig settings), or reopened, refusing settings that differ from its own
        (ValueError, one line). Returns the ``Study``."""
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
