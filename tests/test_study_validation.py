"""Validation (study/validation.py) without running a trial: which trials run again, on which
seeds, with which settings, what is kept and what a second call reuses; the seeds refused; a run
taken to its end from any state; the trial a preset is written from, in either direction."""
from types import SimpleNamespace

import pytest
from optuna.distributions import FloatDistribution
from optuna.trial import TrialState, create_trial

from trl_dgpq.collectors import runner
from trl_dgpq.collectors.experiment import resolve_config
from trl_dgpq.study import validation as validation_module
from trl_dgpq.study.study import Study

from tests.test_study_parts import SQUARE, open_study

pytestmark = pytest.mark.usefixtures("own_tuned_file")   # never the checkout's tuned.json


def add(study, value, setting, state=TrialState.COMPLETE, first=False, key="lipschitz"):
    """A trial of the study's storage, its settings as a trial keeps them. A new study holds trial 0,
    the base preset's, waiting: ``first`` completes it, the others come after it."""
    loaded = study.load()
    if first:
        trial = loaded.ask()
        assert trial.number == 0 and "first" in trial.user_attrs
        trial.set_user_attr("settings", {key: setting})
        loaded.tell(trial, value)
        return
    loaded.add_trial(create_trial(
        state=state, value=value if state == TrialState.COMPLETE else None, params={key: setting},
        distributions={key: FloatDistribution(1e-6, 100.0, log=True)}, user_attrs={"settings": {key: setting}}))


@pytest.fixture
def ran(monkeypatch):
    """Runs made by ``validate`` recorded, not run: (path, config) each; a run's value is its
    agent's lipschitz x 10 + its first seed / 10,000, so a test tells which seeds each ran on."""
    made = []
    monkeypatch.setattr(Study, "run_to_end", staticmethod(lambda path, config: made.append((path, config))))
    monkeypatch.setattr(validation_module, "load_run", lambda path: next(c for p, c in made if p == path))
    monkeypatch.setattr(validation_module, "stage", lambda config, stage: made.append(("staged", stage)) or config)
    monkeypatch.setattr(Study, "tidy", staticmethod(lambda path: made.append(("tidied", path))))
    return made


def scored(study):
    study.objective = SimpleNamespace(direction=study.objective.direction, name="score",
                                      value=lambda config: config["agent"]["lipschitz"] * 10
                                      + config["run"]["seeds"][0] / 10_000)
    return study


def test_the_k_best_trials_and_the_base_presets_run_again_on_the_validation_seeds(tmp_path, ran):
    study = scored(open_study(tmp_path))
    add(study, 9.0, 1.0, first=True)                 # the base preset's, the worst
    add(study, 3.0, 2.0)
    add(study, 1.0, 3.0)
    add(study, None, 4.0, state=TrialState.PRUNED)
    add(study, 2.0, 5.0)
    lines = []
    assert study.validate(2, [1006, 1005, 1005], log=lines.append) == {2: 30.1005, 4: 50.1005, 0: 10.1005}
    runs = [(p, c) for p, c in ran if p not in ("tidied", "staged")]
    assert [p for p, _ in runs] == [tmp_path / "s" / "validation" / n for n in ("0002", "0004", "0000")]
    assert [c["agent"]["lipschitz"] for _, c in runs] == [3.0, 5.0, 1.0]
    assert all(c["run"]["seeds"] == [1005, 1006] and c["run"]["episodes"] == 4 for _, c in runs)
    assert [p for t, p in ran if t == "tidied"] == [p for p, _ in runs]           # each tidied after it ran
    assert lines == ["trial 2: score 30.1005 on the validation seeds 1005-1006 (1 on the tuning seeds)",
                     "trial 4: score 50.1005 on the validation seeds 1005-1006 (2 on the tuning seeds)",
                     "trial 0: score 10.1005 on the validation seeds 1005-1006 (9 on the tuning seeds, the base preset)"]
    assert study.load().user_attrs["validation"] == {"seeds": [1005, 1006],
                                                    "values": {"2": 30.1005, "4": 50.1005, "0": 10.1005}}


def test_a_trials_config_is_the_studys_request_with_its_settings_and_the_validation_seeds(tmp_path, ran):
    study = scored(open_study(tmp_path, {"reward": "paper", "noise_var": "0.02"}))
    add(study, 1.0, 3.0)
    study.validate(1, [1010], log=lambda line: None)
    (_, config), = [(p, c) for p, c in ran if p not in ("tidied", "staged")]
    expected = resolve_config({**SQUARE, "reward": "paper", "noise_var": "0.02", "seeds": "1010-1010",
                               "agent.lipschitz": 3.0})
    assert config == expected and config["env"]["reward"] == "paper"


def test_each_run_is_scored_at_the_studys_last_stage(tmp_path, ran):
    study = scored(open_study(tmp_path, tune={"stages": (0.25, 0.5, 1.0)}))
    add(study, 1.0, 3.0)
    add(study, 2.0, 4.0)
    study.validate(2, [1005], log=lambda line: None)
    assert study.stages[-1] == {"episodes": 4, "env_steps": 0} != study.stages[-2]
    assert [stage for what, stage in ran if what == "staged"] == [study.stages[-1]] * 2


def test_a_maximised_objective_ranks_the_highest_first(tmp_path, ran):
    study = open_study(tmp_path, {"env": "gym:CartPole-v1", "agent": "dqn"})
    study.objective = SimpleNamespace(direction="maximize", name="return", value=lambda config: 0.0)
    for value, lr in ((5.0, 1e-3), (7.0, 2e-3), (6.0, 3e-3)):
        add(study, value, lr, key="lr")
    assert list(study.validate(1, [1005], log=lambda line: None)) == [2]
    assert list(study.validate(2, [1005], log=lambda line: None)) == [2, 3]


def test_a_second_call_reuses_each_value_on_the_same_seeds_and_starts_over_on_others(tmp_path, ran):
    study = scored(open_study(tmp_path))
    add(study, 2.0, 1.0)
    add(study, 1.0, 2.0)
    study.validate(1, [1005], log=lambda line: None)
    ran.clear()
    lines = []
    assert study.validate(2, [1005], log=lines.append) == {2: 20.1005, 1: 10.1005}
    assert [p for p, _ in ran if p not in ("tidied", "staged")] == [tmp_path / "s" / "validation" / "0001"]   # trial 2 kept
    assert lines[0] == "trial 2: score 20.1005 on the validation seeds 1005-1005 (1 on the tuning seeds)"
    ran.clear()
    assert study.validate(1, [1007], log=lambda line: None) == {2: 20.1007}
    assert study.load().user_attrs["validation"] == {"seeds": [1007], "values": {"2": 20.1007}}


def test_a_run_that_fails_keeps_the_values_already_measured(tmp_path, ran, monkeypatch):
    study = scored(open_study(tmp_path))
    add(study, 1.0, 1.0)
    add(study, 2.0, 2.0)

    def second_fails(path, config):
        if path.name == "0002":
            raise RuntimeError("stopped")
        ran.append((path, config))
    monkeypatch.setattr(Study, "run_to_end", staticmethod(second_fails))
    with pytest.raises(RuntimeError):
        study.validate(2, [1005], log=lambda line: None)
    assert study.load().user_attrs["validation"] == {"seeds": [1005], "values": {"1": 10.1005}}


def test_nothing_to_validate_without_a_complete_trial(tmp_path, ran):
    study = open_study(tmp_path)
    add(study, None, 1.0, state=TrialState.PRUNED)
    with pytest.raises(ValueError) as err:
        study.validate(1, [1005])
    assert str(err.value) == "no trial has completed: there is nothing to validate" and not ran


def test_validation_seeds_are_sorted_and_neither_reporting_nor_the_studys_own(tmp_path):
    study = open_study(tmp_path, {"seeds": "1000-1004"})
    assert study.validation_seeds([1012, 1005, 1012]) == [1005, 1012]
    with pytest.raises(ValueError) as err:
        study.validation_seeds([1003, 1004, 1005])
    assert str(err.value) == ("validation seeds [1003, 1004] are the study's own tuning seeds: validate on others, "
                              "e.g. --validation-seeds 1005-1014")
    with pytest.raises(ValueError) as err:
        study.validation_seeds([5, 1005])
    assert str(err.value) == ("validation seeds [5] are reporting seeds: studies and validations never touch the "
                              "reporting seeds 0-99 (reports and make compare use them); use e.g. 1005-1014")


def test_the_trial_a_preset_is_written_from_is_the_best_validated_in_the_studys_direction(tmp_path):
    study = open_study(tmp_path)
    add(study, 1.0, 1.0)
    add(study, 2.0, 2.0)
    add(study, 3.0, 3.0)
    loaded = study.load()
    trial, value = study.best_trial(loaded)
    assert (trial.number, value) == (1, None)                          # not validated: the tuning seeds' best
    loaded.set_user_attr("validation", {"seeds": [1005], "values": {"1": 5.0, "3": 4.0, "2": 6.0}})
    trial, value = study.best_trial(loaded)
    assert (trial.number, value) == (3, 4.0)
    study.objective = SimpleNamespace(direction="maximize")
    trial, value = study.best_trial(loaded)
    assert (trial.number, value) == (2, 6.0)


# ------------------------------------------------------------------ a run to its end
def tiny(seeds="1005-1005", episodes="2"):
    return resolve_config({"env": "corridor", "agent": "random", "seeds": seeds, "episodes": episodes})


def test_a_run_is_started_without_a_progress_bar_and_a_finished_one_left_alone(tmp_path, capfd):
    path = tmp_path / "v" / "0003"
    capfd.readouterr()
    Study.run_to_end(path, tiny())
    assert capfd.readouterr().err == ""
    folder = runner.RunFolder(path)             # read, not held
    assert folder.finished() and folder.read_json(runner.CONFIG)["run"]["seeds"] == [1005]
    before = (path / "episodes.csv").stat().st_mtime_ns
    Study.run_to_end(path, tiny())
    assert (path / "episodes.csv").stat().st_mtime_ns == before


@pytest.mark.parametrize("changed", ["run", "env", "agent"])
def test_a_run_with_other_settings_is_started_over(tmp_path, changed):
    """Each section alone differs (the agent's by one setting of the same agent, so that only the
    agent section's comparison can start it over)."""
    path = tmp_path / "v"
    constant = lambda action: resolve_config({"env": "corridor", "agent": "constant", "action": action,  # noqa: E731
                                              "seeds": "1005-1005", "episodes": "2"})
    first = constant("right") if changed == "agent" else tiny()
    Study.run_to_end(path, first)
    other = constant("left") if changed == "agent" else tiny()
    other[changed] = {**other[changed], **{"run": {"episodes": 3}, "env": {"length": 5}, "agent": {}}[changed]}
    assert [s for s in ("run", "env", "agent") if first[s] != other[s]] == [changed]
    Study.run_to_end(path, other)
    recorded = runner.RunFolder(path).read_json(runner.CONFIG)
    assert recorded[changed] == other[changed] and runner.RunFolder(path).finished()


def test_an_unfinished_run_is_resumed_from_its_folder(tmp_path, monkeypatch):
    path = tmp_path / "v"
    Study.run_to_end(path, tiny())
    folder = runner.RunFolder(path)
    folder.write_json(runner.STATUS, {**folder.status(), "status": "interrupted"})
    resumed = []
    monkeypatch.setattr(runner, "resume", lambda f, config, progress: resumed.append((f.path, config, progress)))
    monkeypatch.setattr(runner, "start", lambda *a, **k: pytest.fail("started over"))
    # the config passed carries a section the run does not record: the resume reads the folder's, not it
    Study.run_to_end(path, {**tiny(), "study": {"trial": 3}})
    assert resumed == [(folder.path, {k: tiny()[k] for k in ("run", "env", "agent")}, False)]
    runner.RunFolder.existing(path).release()          # released after the resume: free to take
