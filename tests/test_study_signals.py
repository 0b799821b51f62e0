"""Signals outside a run (trl_dgpq/study/signals.py), with real signals sent to this process."""
import os
import signal

import pytest

from trl_dgpq.study.signals import Stopped, held, stop_on_signals


def send(signum):
    os.kill(os.getpid(), signum)


@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM])
def test_a_signal_outside_a_held_block_stops_at_once_and_the_old_handlers_come_back(signum):
    seen = []
    mine = lambda s, f: seen.append(s)  # noqa: E731
    old = {s: signal.signal(s, mine) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        after = []
        with pytest.raises(Stopped, match=f"^interrupted by {signal.Signals(signum).name}$") as err:
            with stop_on_signals() as state:
                send(signum)
                after.append("ran on")
        assert err.value.signum == signum and state["signum"] == signum and after == []
        assert signal.getsignal(signal.SIGINT) is mine and signal.getsignal(signal.SIGTERM) is mine
        send(signum)
        assert seen == [signum]
    finally:
        for s, h in old.items():
            signal.signal(s, h)


def test_a_signal_in_a_held_block_waits_for_its_end_and_a_second_one_is_ignored():
    done = []
    with pytest.raises(Stopped) as err:
        with stop_on_signals() as state:
            with held(state):
                send(signal.SIGTERM)
                assert state["held"] and state["signum"] == signal.SIGTERM
                send(signal.SIGINT)               # while stopping: ignored
                done.append("the block finished")
            done.append("never")
    assert err.value.signum == signal.SIGTERM and done == ["the block finished"] and not state["held"]


def test_a_block_without_a_signal_goes_on_and_a_signal_the_runner_caught_stops_at_its_end():
    with stop_on_signals() as state:
        with held(state):
            pass
        assert state == {"signum": None, "held": False}
        state["signum"] = signal.SIGINT                # the runner caught it and checkpointed
        with pytest.raises(Stopped, match="^interrupted by SIGINT$"):
            with held(state):
                pass
