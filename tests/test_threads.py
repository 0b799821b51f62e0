"""Torch threads: a setting (default 1, measured), recorded; used by a run; one per sweep job."""
import pytest
import torch

from trl_dgpq.collectors.experiment import resolve_config, run_experiment
from trl_dgpq.collectors.sweep import _with_seeds


def test_the_default_is_one_thread_and_a_choice_is_recorded():
    assert resolve_config(agent="dqn", seeds=10)["run"]["threads"] == 1
    assert resolve_config(agent="dqn", seeds=10, threads=2)["run"]["threads"] == 2


def test_a_run_uses_the_recorded_threads():
    before = torch.get_num_threads()
    try:
        for n in (2, 1):
            run_experiment(resolve_config(agent="random", seeds=[0], episodes=1, max_steps=3, threads=n),
                           progress=False)
            assert torch.get_num_threads() == n
    finally:
        torch.set_num_threads(before)


def test_sweep_jobs_run_at_one_thread():
    cfg = resolve_config(agent="dqn", seeds=4, threads=2)
    assert _with_seeds(cfg, [0, 1])["run"]["threads"] == 1


@pytest.mark.parametrize("bad", [0, -1])
def test_fewer_than_one_thread_is_refused(bad):
    with pytest.raises(ValueError, match="threads"):
        resolve_config(threads=bad)
