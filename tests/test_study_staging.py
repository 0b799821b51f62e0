"""A trial's run stage by stage (study/staging.py), without the tuner around it: how each way a
run ends is told to the study and logged, which stages are lengthened, reported and pruned at,
where a retried trial's run goes on, and what an ended trial's folder keeps."""
import math
import signal
from types import SimpleNamespace

import optuna
import pytest
from optuna.trial import TrialState

from trl_dgpq.collectors import runner
from trl_dgpq.study import staging as staging_module
from trl_dgpq.study.signals import Stopped

from tests.test_study_parts import open_study

pytestmark = pytest.mark.usefixtures("own_tuned_file")   # never the checkout's tuned.json


@pytest.fixture
def study(tmp_path, monkeypatch):
    """A square study (4 episodes, stages at 1, 2 and 4 episodes) whose objective is called
    "score"; ended trials' tidying and retries recorded, not done."""
    s = open_study(tmp_path, tune={"stages": (0.25, 0.5, 1.0)})
    s.objective = SimpleNamespace(direction="minimize", name="score", value=lambda run: run)
    s.made = []
    monkeypatch.setattr(s, "tidy", lambda path: s.made.append(("tidied", path)))
    monkeypatch.setattr(s, "retry", lambda study, trial, reason: s.made.append(
        ("retried", getattr(study, "study_name", None), trial.number, reason)))
    return s


def retry(loaded, of: int, stopped=None):
    """The retry of trial ``of``, asked of ``loaded`` (a study's Optuna study), as the retry mechanism
    enqueues it; ``stopped``, a running trial, is ended first."""
    if stopped is not None:
        loaded.tell(stopped, 1.0)
    loaded.enqueue_trial({}, user_attrs={"retry_of": of})
    return loaded.ask()


def ended(study, monkeypatch, outcome, stop=None, retry_of=None):
    """Trial 0 (or, with ``retry_of``, trial 1 as its retry) run by ``run`` with ``run_stages``
    stubbed: it sets the trial's settings and returns ``outcome`` or raises it. (trial, log, stop)."""
    loaded = study.load()
    trial = loaded.ask()
    if retry_of is not None:
        trial = retry(loaded, retry_of, stopped=trial)

    def stages(t):
        t.set_user_attr("settings", {"lipschitz": 2.5, "hidden": [64, 64]})
        if isinstance(outcome, BaseException):
            raise outcome
        return outcome
    monkeypatch.setattr(study, "run_stages", stages)
    log, stop = [], stop or {"signum": None, "held": False}
    study.run(trial, stop, log.append)
    return study.load().trials[trial.number], log, stop


def test_a_value_is_told_logged_with_the_settings_and_the_folder_tidied(study, monkeypatch):
    trial, log, _ = ended(study, monkeypatch, 0.125)
    assert trial.state == TrialState.COMPLETE and trial.value == 0.125
    assert log == ["trial 0: score 0.125 with lipschitz=2.5, hidden=64,64"]
    assert study.made == [("tidied", study.folder(0))]


def test_a_retried_trial_names_the_trial_whose_run_it_continued(study, monkeypatch):
    trial, log, _ = ended(study, monkeypatch, 3.0, retry_of=0)
    assert trial.number == 1 and trial.state == TrialState.COMPLETE
    assert log == ["trial 1 (the retry of trial 0, its run continued): score 3 with lipschitz=2.5, hidden=64,64"]


def test_no_seed_ending_an_episode_fails_the_trial_in_words(study, monkeypatch):
    trial, log, _ = ended(study, monkeypatch, math.nan)
    assert trial.state == TrialState.FAIL and trial.user_attrs["error"] == "no seed ended an episode within the budget"
    assert log == ["trial 0: failed: no seed ended an episode within the budget"]
    assert study.made == [("tidied", study.folder(0))]


@pytest.mark.parametrize("error, words", [
    (RuntimeError("the kernel matrix is singular\nat n = 12"), "RuntimeError: the kernel matrix is singular"),
    (ValueError(), "ValueError: "),
])
def test_the_trials_own_error_fails_it_with_the_first_line_and_the_study_goes_on(study, monkeypatch, error, words):
    trial, log, _ = ended(study, monkeypatch, error)
    assert trial.state == TrialState.FAIL and trial.user_attrs["error"] == words
    assert log == [f"trial 0: failed: {words}"] and study.made == [("tidied", study.folder(0))]


def test_a_pruned_trial_is_told_pruned_with_where(study, monkeypatch):
    trial, log, _ = ended(study, monkeypatch, optuna.TrialPruned("at 2 episodes (score 7)"))
    assert trial.state == TrialState.PRUNED and trial.value is None
    assert log == ["trial 0: pruned at 2 episodes (score 7)"] and study.made == [("tidied", study.folder(0))]


@pytest.mark.parametrize("stopped", [Stopped(signal.SIGTERM), runner.Interrupted(signal.SIGTERM, None, 3)])
def test_a_signal_hands_the_trial_to_a_retry_and_stops(study, monkeypatch, stopped):
    """Stopped outside the run or Interrupted inside it (the runner checkpointed): the trial goes to
    a retry, nothing is told or tidied, and the study stops with that signal."""
    with pytest.raises(Stopped) as err:
        ended(study, monkeypatch, stopped)
    assert err.value.signum == signal.SIGTERM
    assert study.made == [("retried", study.load().study_name, 0, "interrupted by SIGTERM")]   # the trial's study
    assert study.load().trials[0].state == TrialState.RUNNING          # (retry stubbed: it would fail it)


def test_the_first_signal_is_the_one_a_stop_reports(study, monkeypatch):
    stop = {"signum": signal.SIGINT, "held": False}      # SIGINT came first; the run then stopped on SIGTERM
    with pytest.raises(Stopped) as err:
        ended(study, monkeypatch, runner.Interrupted(signal.SIGTERM, None, 3), stop=stop)
    assert err.value.signum == signal.SIGINT and stop["signum"] == signal.SIGINT


# (a signal while the trial is told: test_tune's test_a_signal_while_a_trial_is_recorded_lets_the_record_finish,
# with a real SIGINT)


# ------------------------------------------------------------------ run_stages
class Folder:
    def __init__(self, made):
        self.made = made

    def acquire(self):
        self.made.append("acquire")

    def release(self):
        self.made.append("release")


@pytest.fixture
def staged(study, monkeypatch):
    """run_stages with the run stubbed: open_run gives a run of ``study.now`` episodes; lengthening,
    resuming and each stage's objective recorded (stage k's value: ``study.values[episodes]``)."""
    made = study.made
    study.now, study.values = 1, {1: 5.0, 2: 4.0, 4: 3.0}

    folder = Folder(made)

    def open_run(trial, path, config):
        made.append(("open", path, config))
        study.opened_for, study.path = trial, path
        return folder, {"run": {"episodes": study.now, "env_steps": 0}}

    def same(other, what):
        if other is not folder:
            pytest.fail(f"another folder {what}")
    monkeypatch.setattr(study, "open_run", open_run)
    monkeypatch.setattr(runner, "resumable_config", lambda f, lengthen=False: same(f, "read") or made.append(
        ("config", lengthen)) or {"run": {"episodes": study.now, "env_steps": 0}})
    monkeypatch.setattr(runner, "lengthen", lambda f, config, episodes, env_steps: same(f, "lengthened") or made.append(
        ("lengthen", episodes, env_steps)) or {"run": {"episodes": episodes, "env_steps": env_steps}})
    monkeypatch.setattr(runner, "resume", lambda f, config, progress: same(f, "resumed") or made.append(
        ("resume", config, progress)))
    monkeypatch.setattr(staging_module, "load_run", lambda path: ("the run in", path))
    monkeypatch.setattr(staging_module, "stage", lambda run, lengths: (run, lengths["episodes"]))
    # each stage scored on the trial's own run, cut to the stage's length
    study.objective.value = lambda staged_run: study.values[staged_run[1]] if staged_run[0] == (
        "the run in", study.path) else pytest.fail(f"scored {staged_run[0]}")
    return study


def test_each_stage_not_yet_run_is_lengthened_to_and_all_but_the_last_reported(staged):
    trial = staged.load().ask()
    assert staged.run_stages(trial) == 3.0
    path = staged.folder(0)
    opened = staged.made[0]
    assert opened[:2] == ("open", path)
    assert staged.made[1:] == ["acquire", ("config", True), ("lengthen", 2, 0), ("resume", {"run": {"episodes": 2, "env_steps": 0}}, False),
                               "acquire", ("config", True), ("lengthen", 4, 0), ("resume", {"run": {"episodes": 4, "env_steps": 0}}, False),
                               "release"]
    assert trial.storage.get_trial(trial._trial_id).intermediate_values == {1: 5.0, 2: 4.0}
    assert staged.opened_for is trial


def test_a_count_of_env_steps_is_drawn_as_a_fraction_of_the_studys_budget(tmp_path, monkeypatch):
    """DQN's exploration_steps on a 400-step budget: a fraction in [0.05, 0.5] of it (Optuna's
    ``exploration_steps_fraction``), not a count from the episode-budget range (500-20,000)."""
    study = open_study(tmp_path, {"agent": "dqn", "env_steps": "400"}, name="dqn")
    made = []
    monkeypatch.setattr(study, "open_run", lambda trial, path, config: made.append(config) or pytest.fail("drawn"))
    trial = study.load().ask()
    with pytest.raises(pytest.fail.Exception):
        study.run_stages(trial)
    fraction = trial.storage.get_trial(trial._trial_id).params["exploration_steps_fraction"]
    assert 20 <= made[0]["agent"]["exploration_steps"] == max(1, round(fraction * 400)) <= 200


def test_a_trials_config_is_the_studys_request_with_its_drawn_settings(staged, monkeypatch):
    monkeypatch.setitem(staged.request["given"], "reward", "paper")     # an env setting the study was given
    trial = staged.load().ask()
    staged.run_stages(trial)
    config = staged.made[0][2]
    settings = trial.storage.get_trial(trial._trial_id).user_attrs["settings"]
    assert sorted(settings) == sorted(staged.space) and config["run"]["seeds"] == [1000, 1001]
    agent = config["agent"]
    assert {k: agent["gp"][k] if k in ("lengthscale", "noise_var") else agent[k] for k in settings} == settings
    assert config["run"]["episodes"] == 4 and config["env"]["reward"] == "paper"


def test_a_run_already_past_a_stage_is_not_lengthened_and_a_stage_without_a_value_not_reported(staged):
    staged.now, staged.values = 2, {1: math.nan, 2: 4.0, 4: 3.0}
    trial = staged.load().ask()
    assert staged.run_stages(trial) == 3.0
    assert [m for m in staged.made if m[0] == "lengthen"] == [("lengthen", 4, 0)]
    assert trial.storage.get_trial(trial._trial_id).intermediate_values == {2: 4.0}


def test_the_last_stages_value_is_returned_even_without_one(staged):
    staged.values = {1: 5.0, 2: 4.0, 4: math.nan}
    assert math.isnan(staged.run_stages(staged.load().ask()))


def test_a_pruned_stage_says_where_and_the_folder_is_released(staged, monkeypatch):
    trial = staged.load().ask()
    monkeypatch.setattr(trial, "should_prune", lambda: trial.storage.get_trial(trial._trial_id).intermediate_values
                        == {1: 5.0, 2: 4.0})
    with pytest.raises(optuna.TrialPruned) as err:
        staged.run_stages(trial)
    assert str(err.value) == "at 2 episodes (score 4)"
    assert staged.made[-1] == "release" and ("lengthen", 4, 0) not in staged.made


def test_a_stage_by_env_steps_is_named_in_env_steps(staged, monkeypatch):
    staged.stages = [{"episodes": 9, "env_steps": 1500}, {"episodes": 9, "env_steps": 3000}]
    staged.values = {9: 2.0}
    monkeypatch.setattr(staging_module, "covers", lambda now, lengths: True)
    trial = staged.load().ask()
    monkeypatch.setattr(trial, "should_prune", lambda: True)
    with pytest.raises(optuna.TrialPruned) as err:
        staged.run_stages(trial)
    assert str(err.value) == "at 1,500 env steps (score 2)"
    assert trial.storage.get_trial(trial._trial_id).intermediate_values == {1500: 2.0}


def test_a_retry_takes_over_the_stopped_trials_folder_unless_it_has_one(staged):
    loaded = staged.load()
    first = loaded.ask()
    staged.folder(0).mkdir(parents=True)
    (staged.folder(0) / "episodes.csv").write_text("rows")
    staged.run_stages(retry(loaded, 0, stopped=first))
    assert not staged.folder(0).exists() and (staged.folder(1) / "episodes.csv").read_text() == "rows"
    again = retry(loaded, 1)
    staged.folder(2).mkdir()
    staged.run_stages(again)                                 # its own folder exists: the old one stays
    assert staged.folder(1).exists()
    last = retry(loaded, 7)
    staged.run_stages(last)                                  # the old folder is gone: nothing to take
    assert last.number == 3 and not staged.folder(3).exists()


# ------------------------------------------------------------------ open_run and tidy
def small(study, lipschitz=1.0):
    from trl_dgpq.collectors.experiment import resolve_config
    return resolve_config({**study.request["given"], "agent.lipschitz": lipschitz})


def test_a_new_trials_run_starts_its_first_stage(study, capfd):
    trial = study.load().ask()
    path = study.folder(0)
    capfd.readouterr()
    folder, now = study.open_run(trial, path, small(study))
    folder.release()
    assert capfd.readouterr().err == ""                              # no progress bar: the study logs its own lines
    assert now["run"]["episodes"] == 1 and now["run"]["seeds"] == [1000, 1001]
    assert runner.RunFolder(path).read_json(runner.CONFIG)["run"]["episodes"] == 1
    assert runner.RunFolder(path).finished() and "resumed" not in trial.user_attrs


def test_a_retried_trials_run_goes_on_and_other_settings_start_over(study, monkeypatch):
    trial = study.load().ask()
    path = study.folder(0)
    study.open_run(trial, path, small(study))[0].release()
    # finished: taken as it is, its sections as recorded
    folder, now = study.open_run(trial, path, small(study))
    folder.release()
    recorded = runner.RunFolder(path).read_json(runner.CONFIG)
    assert now == {k: recorded[k] for k in ("run", "env", "agent")} and now["run"]["episodes"] == 1
    assert trial.user_attrs["resumed"] == {"from_trial": None, "episodes_done": 2}   # 2 seeds x 1 episode
    # interrupted, by the retry of trial 0 (whose folder it took over): resumed with its own config
    runner.RunFolder(path).write_json(runner.STATUS, {**runner.RunFolder(path).status(), "status": "interrupted"})
    again = retry(study.load(), 0, stopped=trial)
    resumed = []
    with monkeypatch.context() as patched:
        patched.setattr(runner, "resume", lambda f, config, progress: resumed.append((f.path, config, progress)))
        folder, now = study.open_run(again, path, {**small(study), "note": "not recorded"})
        folder.release()
        assert resumed == [(path, now, False)] and now == {k: recorded[k] for k in ("run", "env", "agent")}
        assert again.user_attrs["resumed"] == {"from_trial": 0, "episodes_done": 2}
        for name in (runner.CHECKPOINT, *runner.FALLBACKS):              # stopped before its first checkpoint
            (path / name).unlink(missing_ok=True)
        study.open_run(again, path, small(study))[0].release()
        assert again.user_attrs["resumed"] == {"from_trial": 0, "episodes_done": 0}
    # another agent setting: started over
    folder, now = study.open_run(trial, path, small(study, lipschitz=2.0))
    folder.release()
    assert runner.RunFolder(path).read_json(runner.CONFIG)["agent"]["lipschitz"] == 2.0 == now["agent"]["lipschitz"]


def test_an_ended_trials_folder_keeps_its_rows_config_and_status_only(tmp_path):
    from trl_dgpq.study.staging import Staging
    for name in ("config.json", "status.json", "episodes.csv", "checkpoint.pt", "checkpoint.prev.pt", "lock"):
        (tmp_path / name).write_text("x")
    (tmp_path / "figures").mkdir()
    Staging.tidy(tmp_path)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["config.json", "episodes.csv", "figures", "status.json"]
    Staging.tidy(tmp_path / "absent")                       # nothing there: nothing to do
