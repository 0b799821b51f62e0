"""tune's command (commands/tune.py) with the study stubbed: what it checks before a study is
opened, what it prints and returns at each end (done, a signal, validation, a preset written),
and how its worker processes' ends become its own."""
import signal
from types import SimpleNamespace

import pytest

import trl_dgpq.study
from tests.fake_process import FakeProcess, fake_context
from trl_dgpq.collectors import runner
from trl_dgpq.commands import tune
from trl_dgpq.presets import default_preset


class FakeStudy:
    """What tune's main asks of a study, each call recorded in ``calls``; ``outcomes`` what the
    stubs give back ("signum": the workers' stop, "outcome": validation's end)."""
    calls = []
    outcomes = {}

    def __init__(self, out, storage, given, tune_given):
        self.out, self.url, self.loads = out, storage or f"sqlite:///{out}/study.db", 0
        self.tune = SimpleNamespace(trials=int(tune_given.get("trials", 3)), workers=int(tune_given.get("workers", 1)))
        # a study on the square's default preset writes "tuned"
        preset = given.get("preset", default_preset("square"))
        self.config = {"run": {"env": "square", "agent": "dqn", "preset": preset}}
        self.objective = SimpleNamespace(text="steps to 30", direction="minimize")
        self.calls.append(("open", out, storage, given, tune_given))

    open = classmethod(lambda cls, out, storage, given, tune_given: cls(out, storage, given, tune_given))

    def validation_seeds(self, seeds):
        self.calls.append(("validation seeds", seeds))
        if seeds == [1000]:
            raise ValueError("validation seeds [1000] are the study's own tuning seeds")
        return seeds

    def load(self):
        """A fresh read of the storage: each one finds a trial more done (what a run left)."""
        self.loads += 1
        return self.loads

    def done(self, loaded):
        return 1 + loaded

    def summary(self, trials):
        return f"best of {trials}"

    def validate(self, k, seeds, log):
        self.calls.append(("validate", k, seeds))
        outcome = self.outcomes.get("outcome")
        if isinstance(outcome, BaseException):
            raise outcome
        log("trial 1: score 4")

    def replaces(self, name):
        self.calls.append(("replaces", name))
        return "preset 'tuned' of study s (12 trials)" if name == "tuned" else None

    def write_preset(self, name, force):
        """As the study does: no name, the study's own preset's (the name ``replaces`` was asked of)."""
        self.calls.append(("write", name, force))
        if name == "bad":
            raise ValueError("a preset of another domain")
        return name or next(c[1] for c in reversed(self.calls) if c[0] == "replaces"), "envs/square/tuned.json"


@pytest.fixture
def fake(monkeypatch):
    FakeStudy.calls, FakeStudy.outcomes = [], {}
    monkeypatch.setattr(trl_dgpq.study, "Study", FakeStudy)
    monkeypatch.setattr(tune, "run_workers", lambda study, trials, workers: FakeStudy.calls.append(
        ("run", trials, workers)) or (0 if isinstance(study, FakeStudy) else pytest.fail("not the study opened"))
        or FakeStudy.outcomes.get("signum", 0))
    return FakeStudy


ARGS = ["--env", "square", "--agent", "dqn", "--out", "s"]


def test_a_study_is_opened_with_the_run_and_tune_settings_apart_then_run(fake, capsys):
    assert tune.main([*ARGS, "--episodes", "4", "--trials", "5", "--seeds", "1000-1001"]) == 0
    (_, out, storage, given, tune_given), run = fake.calls
    assert (out, storage) == ("s", None) and tune_given == {"trials": "5"}      # parsed by the study
    assert given == {"env": "square", "agent": "dqn", "episodes": "4", "seeds": "1000-1001"}
    assert run == ("run", 5, 1)
    assert capsys.readouterr().out == ("study sqlite:///s/study.db: dqn on square, steps to 30 (minimize); 2/5 trials "
                                       "done\nbest of 5\n")                  # (2: the first read of the storage)


def test_the_storage_and_each_set_reach_the_study_and_the_command_line_is_the_processs(fake, monkeypatch):
    monkeypatch.setattr("sys.argv", ["tune.py", *ARGS, "--storage", "postgresql://h/db", "--set", "gp.noise_var=0.2",
                                     "--set", " lr = 0.001"])
    assert tune.main() == 0
    _, out, storage, given, _ = fake.calls[0]
    assert storage == "postgresql://h/db" and given == {"env": "square", "agent": "dqn", "gp.noise_var": "0.2",
                                                        "lr": " 0.001"}   # the key stripped


def test_a_set_without_key_and_value_is_refused_in_one_line(fake, capsys):
    with pytest.raises(SystemExit) as err:
        tune.main([*ARGS, "--set", "lr"])
    assert err.value.code == 2 and capsys.readouterr().err == "tune.py: error: --set wants KEY=VALUE, got 'lr'\n"


def test_every_line_on_standard_output_is_flushed(fake, monkeypatch):
    """tune runs for hours with its output in a log: each line is written as it is printed."""
    printed = []
    monkeypatch.setattr(tune, "print", lambda *a, **k: printed.append((a, k)), raising=False)
    assert tune.main([*ARGS, "--validate", "1"]) == 0
    assert [a[0] for a, _ in printed] == ["study sqlite:///s/study.db: dqn on square, steps to 30 (minimize); 2/3 "
                                          "trials done", "best of 3", "trial 1: score 4"]
    assert all(k == {"flush": True} for _, k in printed)


@pytest.mark.parametrize("flags, words", [
    (["--seeds", "0-4"], "tuning seeds [0, 1, 2, 3, 4] are reporting seeds"),
    (["--validation-seeds", "98-99", "--validate", "1"], "validation seeds [98, 99] are reporting seeds: studies and "
     "validations never touch the reporting seeds 0-99 (reports and make compare use them); use e.g. 1005-1014"),
    (["--validation-seeds", "98-99"], "validation seeds [98, 99] are reporting seeds"),   # checked though unused
    (["--validate", "-1"], "--validate must be >= 0, got -1"),
])
def test_what_is_refused_before_any_study_is_opened(fake, capsys, flags, words):
    with pytest.raises(SystemExit) as err:
        tune.main([*ARGS, *flags])
    assert err.value.code == 2 and words in capsys.readouterr().err and fake.calls == []


def test_seeds_the_study_refuses_for_validation_end_before_any_trial(fake, capsys):
    with pytest.raises(SystemExit) as err:
        tune.main([*ARGS, "--validate", "1", "--validation-seeds", "1000-1000"])
    assert err.value.code == 2 and "the study's own tuning seeds" in capsys.readouterr().err
    assert not any(c[0] == "run" for c in fake.calls)


def test_validation_seeds_are_asked_of_the_study_only_to_validate(fake):
    tune.main(ARGS)
    assert [c[0] for c in fake.calls] == ["open", "run"]
    fake.calls.clear()
    tune.main([*ARGS, "--validate", "2", "--validation-seeds", "1020-1021"])
    assert [c for c in fake.calls if c[0] != "open"] == [("validation seeds", [1020, 1021]), ("run", 3, 1),
                                                          ("validate", 2, [1020, 1021])]


@pytest.mark.parametrize("storage, hint", [([], ""), (["--storage", "sqlite:///x.db"], " --storage sqlite:///x.db")])
def test_a_signal_says_how_far_the_study_got_and_how_to_continue(fake, capsys, storage, hint):
    fake.outcomes["signum"] = signal.SIGTERM
    assert tune.main([*ARGS, "--out", "my study", *storage, "--trials", "7", "--validate", "1"]) == 143
    captured = capsys.readouterr()
    # 3 done: the storage read again after the workers stopped (the header said 2)
    assert captured.err == ("interrupted by SIGTERM: 3/7 trials done; continue with: python scripts/tune.py --out "
                            f"'my study'{hint} --trials 7\n")
    assert "best of" not in captured.out and not any(c[0] == "validate" for c in fake.calls)


def test_validation_logs_its_lines_and_its_ends(fake, capsys):
    assert tune.main([*ARGS, "--validate", "2"]) == 0
    assert capsys.readouterr().out.endswith("best of 3\ntrial 1: score 4\n")
    fake.outcomes["outcome"] = runner.Interrupted(signal.SIGINT, None, 0)
    assert tune.main([*ARGS, "--validate", "2", "--validation-seeds", "1020-1024"]) == 130
    assert capsys.readouterr().err == ("interrupted: continue with: python scripts/tune.py --out s --validate 2 "
                                       "--validation-seeds 1020-1024\n")
    fake.outcomes["outcome"] = ValueError("no trial has completed: there is nothing to validate")
    with pytest.raises(SystemExit) as err:
        tune.main([*ARGS, "--validate", "2"])
    assert err.value.code == 2 and "no trial has completed" in capsys.readouterr().err


def test_a_preset_is_written_under_its_name_and_says_what_it_replaced(fake, capsys):
    assert tune.main([*ARGS, "--write-preset"]) == 0
    assert ("replaces", "tuned") in fake.calls and ("write", None, False) in fake.calls
    assert capsys.readouterr().out.endswith("best of 3\nreplaced preset 'tuned' of study s (12 trials)\nwrote preset "
                                            "'tuned' to envs/square/tuned.json: python scripts/train.py --env square "
                                            "--agent dqn --preset tuned\n")
    assert tune.main([*ARGS, "--write-preset", "late", "--force"]) == 0
    assert ("replaces", "late") in fake.calls and ("write", "late", True) in fake.calls
    out = capsys.readouterr().out
    assert "replaced" not in out and out.endswith("wrote preset 'late' to envs/square/tuned.json: python scripts/"
                                                  "train.py --env square --agent dqn --preset late\n")
    assert tune.main([*ARGS, "--preset", "noisy", "--write-preset"]) == 0
    assert ("replaces", "noisy-tuned") in fake.calls                   # a study on another preset: its own name
    assert capsys.readouterr().out.endswith("wrote preset 'noisy-tuned' to envs/square/tuned.json: python scripts/"
                                            "train.py --env square --agent dqn --preset noisy-tuned\n")
    with pytest.raises(SystemExit) as err:
        tune.main([*ARGS, "--write-preset", "bad"])
    assert err.value.code == 2 and "a preset of another domain" in capsys.readouterr().err


def test_no_preset_is_written_unless_asked(fake):
    tune.main(ARGS)
    assert not any(c[0] in ("replaces", "write") for c in fake.calls)


def test_ctrl_c_before_the_trials_is_one_line(monkeypatch, capsys):
    def stopped(argv):
        raise KeyboardInterrupt
    monkeypatch.setattr(tune, "_main", stopped)
    assert tune.main(ARGS) == 130 and capsys.readouterr().err == "interrupted before the study started\n"


# ------------------------------------------------------------------ run_workers
def test_one_worker_fills_the_study_here_and_returns_the_signal_that_stopped_it(monkeypatch, capsys):
    from trl_dgpq.study import Stopped
    seen = []
    monkeypatch.setattr(tune, "print", lambda *a, **k: print(*a, **k) if k == {"flush": True} else pytest.fail(k),
                        raising=False)

    def work(study, trials, stop, log):
        seen.append((study, trials, set(stop)))
        log("trial 0: score 1")
    monkeypatch.setattr(trl_dgpq.study, "work", work)
    assert tune.run_workers("S", 4, 1) == 0
    assert seen == [("S", 4, {"signum", "held"})] and capsys.readouterr().out == "trial 0: score 1\n"

    def stopped(study, trials, stop, log):
        raise Stopped(signal.SIGTERM)
    monkeypatch.setattr(trl_dgpq.study, "work", stopped)
    assert tune.run_workers("S", 4, 1) == signal.SIGTERM


def workers(monkeypatch, codes, during_join=None):
    fake_context(monkeypatch, tune.multiprocessing, "spawn", codes, on_join=during_join)
    return SimpleNamespace(out="dir", url="sqlite:///dir/study.db", request={"given": {}})


def test_k_workers_are_spawned_on_the_same_study_and_their_ends_read(monkeypatch):
    from trl_dgpq.study import worker
    study = workers(monkeypatch, [0, 0, 0])
    assert tune.run_workers(study, 9, 3) == 0
    assert FakeProcess.log == [("start", 4242), ("start", 4243), ("start", 4244), ("join", 4242), ("join", 4243),
                        ("join", 4244)]                                   # all started, then each waited for
    assert all(p.target is worker and p.args == ("dir", "sqlite:///dir/study.db", {"given": {}}, 9) for p in FakeProcess.made)
    study = workers(monkeypatch, [0, 128 + signal.SIGINT, 128 + signal.SIGTERM])
    assert tune.run_workers(study, 9, 3) == signal.SIGINT                      # the first stopped one's
    study = workers(monkeypatch, [0, 3, 1])
    with pytest.raises(SystemExit) as err:
        tune.run_workers(study, 9, 3)
    assert str(err.value) == "tune.py: a worker ended with exit code 3"
    study = workers(monkeypatch, [1, 128 + signal.SIGTERM])
    assert tune.run_workers(study, 9, 2) == signal.SIGTERM                    # stopped beats failed


def test_a_signal_to_tune_is_sent_on_to_each_live_worker_once(monkeypatch):
    """Three workers; the first has ended when SIGTERM arrives (during the second's join): it goes
    to the two still alive, once; a SIGINT after it is not sent on."""
    killed = []
    monkeypatch.setattr(tune.os, "kill", lambda pid, signum: killed.append((pid, signum)))

    def signal_arrives(proc):
        if proc is FakeProcess.made[1]:
            signal.getsignal(signal.SIGTERM)(signal.SIGTERM, None)
            signal.getsignal(signal.SIGINT)(signal.SIGINT, None)     # a second one: not sent again
    before = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)}
    study = workers(monkeypatch, [0, 0, 0], during_join=signal_arrives)
    assert tune.run_workers(study, 9, 3) == signal.SIGTERM
    assert killed == [(4243, signal.SIGTERM), (4244, signal.SIGTERM)]
    assert {s: signal.getsignal(s) for s in before} == before                 # tune's own handlers put back
