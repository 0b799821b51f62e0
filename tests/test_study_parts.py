"""The study itself (study/study.py) without running a trial: the search space a request leaves,
the column a reopened study keeps scoring, and ``work`` / ``worker``'s loop and exits."""
import signal

import pytest

from trl_dgpq.study import study as study_module
from trl_dgpq.study.config import TuneConfig
from trl_dgpq.study.signals import Stopped
from trl_dgpq.study.study import Study, work, worker
from trl_dgpq.tuning import Factors

SQUARE = {"env": "square", "agent": "dgpq", "episodes": "4", "seeds": "1000-1001"}
DGPQ_SPACE = ["eps1", "lengthscale", "lipschitz", "noise_var", "sigma_tol2"]


pytestmark = pytest.mark.usefixtures("own_tuned_file")   # never the checkout's tuned.json


def open_study(tmp_path, given=None, tune=None, name="s"):
    return Study.open(tmp_path / name, None, {**SQUARE, **(given or {})}, tune or {})


def test_the_space_is_the_agents_less_what_the_command_line_gives(tmp_path):
    study = open_study(tmp_path)
    assert sorted(study.space) == DGPQ_SPACE
    given = open_study(tmp_path, {"lipschitz": "3", "agent.eps1": "0.01", "seeds": "1000-1002"}, name="g")
    assert sorted(given.space) == ["lengthscale", "noise_var", "sigma_tol2"]      # flag or dotted path alike
    assert given.given_agent_env() == {"lipschitz": "3", "agent.eps1": "0.01"}     # the run's settings left out
    assert study.given_agent_env() == {}
    dotted = open_study(tmp_path, {"run.env_steps": "400", "gamma": "0.5"}, name="d")
    assert dotted.given_agent_env() == {"gamma": "0.5"} and dotted.config["run"]["env_steps"] == 400
    ranged = open_study(tmp_path, tune={"search": ("lipschitz=1:4",)}, name="r")
    assert ranged.space["lipschitz"].low == 1.0 and ranged.space["lipschitz"].high == 4.0
    with pytest.raises(ValueError) as err:
        open_study(tmp_path, {k: "0.1" for k in DGPQ_SPACE}, name="all")
    assert str(err.value) == "every setting of the search space is given on the command line: nothing to tune"
    assert not (tmp_path / "all").exists()


def test_weights_given_on_the_command_line_are_the_base_their_factors_scale(tmp_path):
    study = open_study(tmp_path, {"state_scale": "2,0"}, {"search": ("state_scale=0.5:4",)})
    assert study.space["state_scale"] == Factors(0.5, 4.0, (2.0, 0.0))           # given, and still searched
    assert sorted(study.space) == sorted(DGPQ_SPACE + ["state_scale"])


def test_the_objective_and_stages_come_from_the_request(tmp_path):
    study = open_study(tmp_path, {"env_steps": "400"}, {"stages": (0.5, 1.0), "window": 3})
    assert study.stages == [{"episodes": 4, "env_steps": 200}, {"episodes": 4, "env_steps": 400}]
    assert study.objective.name == "steps to threshold" and study.tune == TuneConfig(stages=(0.5, 1.0), window=3)
    assert study.request["scored"] == "steps" and study.name == "s" and study.out == tmp_path / "s"
    assert study.config == study.request["config"] and study.url.endswith("/s/study.db")
    measured = open_study(tmp_path, {"env": "liquidation"}, {"objective": "measure", "window": 3,
                                                             "measure": "noise_free_cost_ratio"}, name="m")
    assert (measured.objective.column, measured.objective.window) == ("noise_free_cost_ratio", 3)


def test_a_study_keeps_scoring_the_column_it_began_on(tmp_path):
    base = open_study(tmp_path, {"env": "liquidation", "episodes": "12"}, {"objective": "worst", "window": 2,
                                                                          "stages": (0.5, 1.0)})
    request = {**base.request, "scored": "ac_cost"}
    worst = Study(tmp_path / "s", base.url, request).objective
    assert (worst.column, worst.direction, worst.window, worst.stages) == ("ac_cost", "minimize", 2, ((12, 0),))
    assert worst.name == "worst ac_cost" and worst.text.endswith("the worst of these; the env's measure when the "
                                                                 "study began), IQM over seeds")
    measure = Study(tmp_path / "s", base.url, {**request, "tune": {**request["tune"], "objective": "measure"}})
    assert (measure.objective.name, measure.objective.stages) == ("ac_cost at budget", ())
    assert measure.objective.text == ("ac_cost at budget (mean of each seed's last 2 episodes; the env's measure "
                                      "when the study began), IQM over seeds")
    same = Study(tmp_path / "s", base.url, dict(base.request))
    assert same.objective == base.objective and same.objective.column == "cost_ratio"


def test_a_setting_is_read_as_the_study_resolved_it_and_no_preset_is_written_without_a_complete_trial(
        tmp_path):
    study = open_study(tmp_path, {"reward": "paper", "gamma": "0.5"})
    assert study.value_of("env", "reward") == "paper" and study.value_of("agent", "gamma") == 0.5
    assert study.value_of("agent", "gp.noise_var") == study.config["agent"]["gp"]["noise_var"]
    with pytest.raises(ValueError) as err:
        study.write_preset("mine")
    assert str(err.value) == "no trial has completed: there is no best trial to write as a preset"
    assert not (tmp_path / "tuned.json").exists()


class Queue:
    def __init__(self, n):
        self.left, self.ran = list(range(n)), []

    def next_trial(self, trials, stop):
        assert trials == 7 and stop == {"signum": None}
        return self.left.pop(0) if self.left else None

    def run(self, trial, stop, log):
        assert stop["signum"] is None                  # the stop it was given, handed on
        self.ran.append(trial)
        log(f"ran {trial}")


def test_work_runs_trials_until_the_study_is_full(monkeypatch):
    import optuna
    optuna.logging.set_verbosity(optuna.logging.INFO)
    queue, lines = Queue(3), []
    work(queue, 7, {"signum": None}, lines.append)
    assert queue.ran == [0, 1, 2] and lines == ["ran 0", "ran 1", "ran 2"]
    assert optuna.logging.get_verbosity() == optuna.logging.WARNING        # quiet for the lines per trial


def test_a_worker_prints_its_lines_and_exits_128_plus_the_signal(monkeypatch, capsys):
    made = []

    def one_line_and_a_trial(study, trials, stop, log):
        log(f"{trials} {stop['signum']}")
        study.run(0, stop, log)
    monkeypatch.setattr(study_module, "Study", lambda out, url, request: made.append((out, url, request)) or Queue(2))
    monkeypatch.setattr(study_module, "work", one_line_and_a_trial)
    assert worker("out", "url", {"r": 1}, 7) is None
    assert made == [("out", "url", {"r": 1})] and capsys.readouterr().out == "7 None\nran 0\n"
    printed = []                                   # each line flushed: a parent reads a worker's pipe as it goes
    with monkeypatch.context() as mp:
        mp.setattr(study_module, "print", lambda *a, **k: printed.append((a, k)), raising=False)
        worker("out", "url", {}, 7)
    assert printed == [(("7 None",), {"flush": True}), (("ran 0",), {"flush": True})]

    def stopped(study, trials, stop, log):
        raise Stopped(signal.SIGTERM)
    monkeypatch.setattr(study_module, "work", stopped)
    with pytest.raises(SystemExit) as exit_:
        worker("out", "url", {}, 7)
    assert exit_.value.code == 143
    before = signal.getsignal(signal.SIGINT)

    def interrupted(study, trials, stop, log):
        assert signal.getsignal(signal.SIGINT) is not before               # its handlers set while it works
        raise Stopped(signal.SIGINT)
    monkeypatch.setattr(study_module, "work", interrupted)
    with pytest.raises(SystemExit) as exit_:
        worker("out", "url", {}, 7)
    assert exit_.value.code == 130 and signal.getsignal(signal.SIGINT) is before
