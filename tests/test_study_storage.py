"""Where a study lives and how it is made or reopened (study/storage.py), without running a trial:
its storage's URL and how provenance records it, the Optuna study's direction and first trial, the
settings a reopened study keeps and those it refuses."""
import warnings
from pathlib import Path

import optuna
import pytest

import trl_dgpq
from trl_dgpq.study import Study
from trl_dgpq.study import storage as storage_module
from trl_dgpq.study.config import TuneConfig
from trl_dgpq.study.storage import open_storage, portable, quiet_optuna, storage_url

ROOT = Path(trl_dgpq.__file__).resolve().parent.parent     # the checkout (or the tree the package runs from)
SQUARE = {"env": "square", "agent": "dqn", "episodes": "4"}


pytestmark = pytest.mark.usefixtures("own_tuned_file")   # never the checkout's tuned.json


def test_a_studys_storage_is_its_folders_sqlite_file_unless_given(tmp_path):
    assert storage_url(tmp_path / "s") == f"sqlite:///{(tmp_path / 's').resolve() / 'study.db'}"
    assert storage_url(tmp_path / "s", "postgresql://host/db") == "postgresql://host/db"


def test_provenance_records_a_file_under_the_checkout_relative_to_it():
    inside = ROOT / "runs" / "tune" / "x" / "study.db"
    assert portable(f"sqlite:///{inside}") == "sqlite:///runs/tune/x/study.db"
    assert portable(f"sqlite:///{ROOT / 'runs' / '..' / 'a.db'}") == "sqlite:///a.db"    # resolved first
    for kept in ("sqlite:////elsewhere/study.db", "sqlite:///relative.db", "postgresql://host/db",
                 f"mysql:///{inside}"):
        assert portable(kept) == kept


def test_a_storage_is_opened_once_per_url_and_sqlite_waits_for_a_busy_file(tmp_path):
    url = f"sqlite:///{tmp_path / 'a.db'}"
    assert open_storage(url) is open_storage(url) and open_storage(url) is not open_storage(url + "x")
    assert open_storage(url).engine_kwargs == {"connect_args": {"timeout": 120}}


def test_optuna_is_quieted_to_warnings_and_its_experimental_warnings_hidden():
    optuna.logging.set_verbosity(optuna.logging.INFO)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        quiet_optuna()
        assert optuna.logging.get_verbosity() == optuna.logging.WARNING
        warnings.warn("an experimental feature", optuna.exceptions.ExperimentalWarning)   # hidden, not raised
        with pytest.raises(UserWarning):
            warnings.warn("another warning")


def test_a_new_study_keeps_its_request_direction_and_first_trial(tmp_path):
    out = tmp_path / "s"
    study = Study.open(out, None, SQUARE, {"window": 7})
    assert out.is_dir() and study.url == storage_url(out) and study.name == "s"
    request = Study.stored_request(study.url, "s")
    assert request == study.request and request["given"] == {"seeds": "1000-1004", **SQUARE}
    assert request["config"]["run"]["seeds"] == [1000, 1001, 1002, 1003, 1004] and request["tune"]["window"] == 7
    assert request["tune"]["trials"] == TuneConfig().trials
    optuna_study = study.load()
    assert optuna_study.direction == optuna.study.StudyDirection.MINIMIZE              # steps to threshold
    (first,) = optuna_study.get_trials()
    assert first.state == optuna.trial.TrialState.WAITING and first.user_attrs == {"first": "preset shaped"}
    assert set(first.system_attrs["fixed_params"]) == set(study.space)
    assert first.system_attrs["fixed_params"]["lr"] == study.config["agent"]["lr"]
    sampled = Study.open(tmp_path / "sampled", None, SQUARE, {"first": "sampled"})
    assert sampled.load().get_trials() == []


def test_a_maximised_objective_makes_a_maximising_study(tmp_path):
    study = Study.open(tmp_path / "f", None, {"env": "f16", "agent": "dqn", "episodes": "4"}, {"objective": "measure"})
    assert study.load().direction == optuna.study.StudyDirection.MAXIMIZE


def test_reporting_seeds_are_refused_before_anything_is_made(tmp_path):
    out = tmp_path / "s"
    with pytest.raises(ValueError, match="tuning seeds"):
        Study.open(out, None, {**SQUARE, "seeds": "0-4"}, {})
    assert not out.exists()


def test_a_study_missing_or_elsewhere_has_no_request_and_no_file_is_made(tmp_path):
    url = f"sqlite:///{tmp_path / 'none.db'}"
    assert Study.stored_request(url, "s") is None and not (tmp_path / "none.db").exists()
    Study.open(tmp_path / "s", None, SQUARE, {})
    assert Study.stored_request(storage_url(tmp_path / "s"), "other") is None


def test_a_reopened_study_takes_new_trials_and_workers_and_refuses_other_settings(tmp_path):
    out = tmp_path / "s"
    made = Study.open(out, None, SQUARE, {"trials": 3})
    again = Study.open(out, None, {}, {"trials": 9, "workers": 2})
    assert again.request["tune"]["trials"] == 9 and again.request["tune"]["workers"] == 2
    assert again.request["given"] == made.request["given"] and again.request["config"] == made.request["config"]
    assert len(again.load().get_trials()) == 1                                      # the first trial not queued again
    assert Study.open(out, None, dict(SQUARE), {}).request["config"] == made.request["config"]   # the same: fine
    with pytest.raises(ValueError) as err:
        Study.open(out, None, {}, {"window": 3})
    assert str(err.value) == "the study keeps its window 10: continue it without --window"
    with pytest.raises(ValueError) as err:
        Study.open(out, None, {}, {"prune_after": 2})
    assert str(err.value) == "the study keeps its prune_after 5: continue it without --prune-after"
    with pytest.raises(ValueError) as err:
        Study.open(out, None, {"gamma": "0.5", "episodes": "5"}, {})
    assert str(err.value) == ("the study was made with other settings (run.episodes, agent.gamma differ): continue it "
                              "with the same settings, or none (--trials and --workers may change)")


def test_a_study_made_before_a_setting_existed_takes_its_default_and_keeps_it():
    stored = {"given": dict(SQUARE), "config": {}, "tune": {"trials": 4}}    # no window recorded: its default
    assert storage_module.Storage.reopen_request(stored, {}, {"trials": 6})["tune"]["window"] == TuneConfig().window
    with pytest.raises(ValueError, match="keeps its window 10"):
        storage_module.Storage.reopen_request(stored, {}, {"window": 11})
    kept = storage_module.Storage.reopen_request(stored, {}, {})
    assert kept["given"] is stored["given"] and kept["tune"]["trials"] == 4


def test_the_first_trial_of_a_budget_in_steps_gives_counts_as_fractions_of_it(tmp_path):
    study = Study.open(tmp_path / "s", None, {**SQUARE, "env_steps": "20000"}, {})
    fixed = study.load().get_trials()[0].system_attrs["fixed_params"]
    assert fixed["exploration_steps_fraction"] == 0.1 and "exploration_steps" not in fixed   # 2,000 of 20,000


def test_studies_sharing_a_storage_are_kept_apart_by_their_folders_names(tmp_path):
    url = f"sqlite:///{tmp_path / 'shared.db'}"
    a = Study.open(tmp_path / "one" / "a", url, SQUARE, {"window": 3})
    b = Study.open(tmp_path / "two" / "deep" / "b", url, SQUARE, {"window": 4})   # its folder's parents made
    assert a.url == b.url == url and not (tmp_path / "one" / "a" / "study.db").exists()
    assert Study.stored_request(url, "a")["tune"]["window"] == 3 and Study.stored_request(url, "b")["tune"]["window"] == 4
    assert a.load().study_name == "a" and b.load().study_name == "b"
    assert sorted(optuna.study.get_all_study_names(url)) == ["a", "b"]


def test_a_loaded_study_prunes_by_the_median_and_samples_by_its_seed_and_trial_count(tmp_path):
    def first_draw(name, seed):
        study = Study.open(tmp_path / name, None, SQUARE, {"first": "sampled", "sampler_seed": seed,
                                                            "prune_after": 2})
        loaded = study.load()
        assert isinstance(loaded.pruner, optuna.pruners.MedianPruner) and loaded.pruner._n_startup_trials == 2
        assert isinstance(loaded.sampler, optuna.samplers.TPESampler)
        return loaded.ask().suggest_float("x", 0.0, 1.0), study
    x, study = first_draw("a", 0)
    assert first_draw("b", 0)[0] == x != first_draw("c", 1)[0]       # the same seed, the same draw
    assert study.load().ask().suggest_float("x", 0.0, 1.0) != x      # the next trial: another seed


def test_a_reopened_study_refuses_a_setting_it_did_not_record():
    from trl_dgpq.collectors.experiment import resolve_config
    config = resolve_config(dict(SQUARE))
    old = {"given": dict(SQUARE), "config": {**config, "agent": {k: v for k, v in config["agent"].items()
                                                                  if k != "gamma"}}, "tune": {}}
    with pytest.raises(ValueError, match=r"\(agent.gamma differ\)"):
        storage_module.Storage.reopen_request(old, {"episodes": "4"}, {})
