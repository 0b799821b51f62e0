"""The study's trial bookkeeping (study/trials.py) on an in-memory Optuna study: which trials count,
the next one a process takes, and those of gone processes retried with their parameters and folder.
test_tune runs the same through whole studies; here each rule is checked alone."""
import os
import signal
import subprocess
import sys
from contextlib import contextmanager

import optuna
import pytest
from optuna.trial import TrialState

from trl_dgpq.study import trials as trials_module
from trl_dgpq.study.config import HOST
from trl_dgpq.study.signals import Stopped
from trl_dgpq.study.trials import Trials


class Book(Trials):
    """Trials over one in-memory study (the Study's storage, lock and folder, stubbed)."""

    def __init__(self, out):
        self.out = out
        self.study = optuna.create_study()
        self.locked = 0

    def load(self):
        return self.study

    @contextmanager
    def lock(self):
        self.locked += 1
        yield


def dead_pid() -> int:
    proc = subprocess.Popen([sys.executable, "-c", "pass"])
    proc.wait()
    return proc.pid


def running(book, host=HOST, pid=None, params=None, **attrs):
    if params is not None:
        book.study.enqueue_trial(params)
    trial = book.study.ask()
    for k, v in dict(host=host, pid=pid, **attrs).items():
        if v is not None:
            trial.set_user_attr(k, v)
    return trial


def test_complete_pruned_and_own_failures_count_retried_and_running_ones_do_not(tmp_path):
    book = Book(tmp_path)
    study = book.study
    for state in (TrialState.COMPLETE, TrialState.PRUNED, TrialState.FAIL, TrialState.FAIL, TrialState.COMPLETE):
        t = study.ask()
        if t.number == 3:
            t.set_user_attr("retried", "process 1 is gone")
        if state == TrialState.COMPLETE:
            study.tell(t, 1.0)
        else:
            study.tell(t, state=state)
    study.ask()                                                      # running
    ended = book.ended(study.get_trials())
    assert {k: [t.number for t in v] for k, v in ended.items()} == {"complete": [0, 4], "pruned": [1], "failed": [2]}
    assert book.done(study) == 4


def test_a_process_takes_trials_marked_with_it_until_ended_and_running_ones_fill_the_study(tmp_path):
    book, stop = Book(tmp_path), {"signum": None, "held": False}
    first = book.next_trial(2, stop)
    assert first.number == 0 and first.user_attrs == {"host": HOST, "pid": os.getpid()} and book.locked == 1
    book.study.tell(first, 0.5)
    running(book, pid=os.getppid())                                    # another live process's
    assert book.next_trial(2, stop) is None                            # one ended and one running fill two
    third = book.next_trial(3, stop)
    assert third.number == 2 and not stop["held"] and book.locked == 3
    # asked again, this process is not running its earlier trial any more: that one is gone, and retried
    again = book.next_trial(5, stop)
    assert book.study.trials[2].state == TrialState.FAIL
    assert book.study.trials[2].user_attrs["retried"] == f"process {os.getpid()} is gone"
    assert again.number == 3 and again.user_attrs == {"retry_of": 2, "host": HOST, "pid": os.getpid()}


def test_a_signal_while_a_trial_is_asked_for_hands_it_on_and_stops(tmp_path):
    book = Book(tmp_path)
    stop = {"signum": signal.SIGTERM, "held": False}                   # as if it came inside the held block
    book.study.enqueue_trial({"lr": 0.5})
    with pytest.raises(Stopped) as err:
        book.next_trial(5, stop)
    assert err.value.signum == signal.SIGTERM
    asked, again = book.study.get_trials()
    assert asked.state == TrialState.FAIL and asked.user_attrs["retried"] == "interrupted by SIGTERM"
    assert again.state == TrialState.WAITING and again.user_attrs == {"retry_of": 0}
    assert again.system_attrs["fixed_params"] == {"lr": 0.5}
    assert book.done(book.study) == 0


def test_trials_of_gone_processes_of_this_machine_are_retried_others_left(tmp_path, monkeypatch):
    book = Book(tmp_path)
    gone = dead_pid()
    mine_gone = running(book, pid=gone, params={"lr": 0.1})
    mine_alive = running(book, pid=os.getppid())
    elsewhere = running(book, host=HOST + "-other", pid=gone)
    unmarked = running(book, host=None)
    book.recover(book.study)
    states = [t.state for t in book.study.get_trials()]
    assert states[:4] == [TrialState.FAIL, TrialState.RUNNING, TrialState.RUNNING, TrialState.RUNNING]
    assert book.study.trials[mine_gone.number].user_attrs["retried"] == f"process {gone} is gone"
    retry = book.study.get_trials()[4]
    assert retry.state == TrialState.WAITING and retry.user_attrs == {"retry_of": mine_gone.number}
    assert retry.system_attrs["fixed_params"] == {"lr": 0.1}
    assert len(book.study.get_trials()) == 5
    monkeypatch.setattr(trials_module, "UNMARKED_S", -1.0)             # the unmarked one is now "long" unmarked
    book.recover(book.study)
    assert book.study.trials[unmarked.number].state == TrialState.FAIL
    assert book.study.trials[unmarked.number].user_attrs["retried"] == "its process never marked it"
    assert book.study.trials[mine_alive.number].state == TrialState.RUNNING
    assert book.study.trials[elsewhere.number].state == TrialState.RUNNING


def test_next_trial_recovers_first(tmp_path):
    book, stop = Book(tmp_path), {"signum": None, "held": False}
    running(book, pid=dead_pid(), params={"lr": 0.3})
    taken = book.next_trial(1, stop)                                   # the gone one's place, its params again
    assert taken.number == 1 and book.study.trials[1].system_attrs["fixed_params"] == {"lr": 0.3}
    assert taken.user_attrs == {"retry_of": 0, "host": HOST, "pid": os.getpid()}


def test_a_retry_keeps_its_parameters_the_folder_owner_and_the_first_mark(tmp_path):
    book = Book(tmp_path)
    drawn = running(book, pid=os.getppid(), first=True)
    drawn.suggest_float("x", 0.0, 1.0)
    book.retry(book.study, drawn, "a reason")
    again = book.study.get_trials()[-1]
    assert again.user_attrs == {"retry_of": 0, "first": True}
    assert again.system_attrs["fixed_params"] == {"x": drawn.params["x"]}
    assert book.study.trials[0].user_attrs["retried"] == "a reason" and book.study.trials[0].state == TrialState.FAIL
    # the retry, taken and stopped in turn: its folder was never made, so the folder stays trial 0's
    taken = book.study.ask()
    assert taken.number == 1 and taken.user_attrs["retry_of"] == 0
    book.retry(book.study, taken, "again")
    assert book.study.get_trials()[-1].user_attrs == {"retry_of": 0, "first": True}
    # once a retry has made its own folder, its own number owns the next retry
    taken = book.study.ask()
    book.folder(taken.number).mkdir(parents=True)
    taken.suggest_float("x", 0.0, 1.0)
    book.retry(book.study, taken, "a third time")
    last = book.study.get_trials()[-1]
    assert last.user_attrs == {"retry_of": taken.number, "first": True} and taken.number == 2
    assert last.system_attrs["fixed_params"] == {"x": drawn.params["x"]}
    # a trial of its own (no retry_of, no folder) is its own owner; one not first is not marked first
    fresh = Book(tmp_path / "fresh")
    own = running(fresh, pid=os.getppid(), params={"x": 0.25})
    fresh.retry(fresh.study, own, "gone")
    assert fresh.study.get_trials()[-1].user_attrs == {"retry_of": 0}
    assert book.folder(7) == tmp_path / "trials" / "0007" and book.folder(12345) == tmp_path / "trials" / "12345"
