"""DDPG from TorchRL parts: seeds independent, its own random streams, the course's sizes."""
import pandas as pd
import pytest
import torch
from torchrl.data import LazyTensorStorage
from torchrl.modules import OrnsteinUhlenbeckProcessModule
from torchrl.objectives import DDPGLoss, SoftUpdate

from trl_dgpq.collectors.experiment import TIMING_COLUMNS, build, resolve_config, run_experiment
from trl_dgpq.collectors.online import OnlineCollector

SMALL = dict(env="liquidation", agent="ddpg", trades=15, batch_size=8, buffer_size=100, episodes=4)


def test_seed_alone_equals_seed_in_a_batch():
    both = run_experiment(resolve_config(seeds=[0, 1], **SMALL), progress=False)
    alone = run_experiment(resolve_config(seeds=[1], **SMALL), progress=False)
    assert both.updates.max() > 10  # learning happened
    pd.testing.assert_frame_equal(both[both.seed == 1].reset_index(drop=True).drop(columns=list(TIMING_COLUMNS)),
                                  alone.drop(columns=list(TIMING_COLUMNS)))
    assert not both[both.seed == 0]["return"].equals(both[both.seed == 1]["return"].reset_index(drop=True))


def test_learners_leave_torchs_global_generator_alone():
    torch.manual_seed(123)
    expected = torch.rand(4)
    torch.manual_seed(123)
    env, agent = build(resolve_config(seeds=[0, 1], **SMALL))
    OnlineCollector(env, agent, 2, progress=False).run()
    assert torch.equal(torch.rand(4), expected)


def test_built_from_torchrl_parts_with_the_course_sizes():
    env, agent = build(resolve_config(env="liquidation", agent="ddpg", seeds=[0]))
    learner = agent.learners[0]
    assert isinstance(learner.loss, DDPGLoss) and isinstance(learner.target, SoftUpdate)
    assert isinstance(learner.ou, OrnsteinUhlenbeckProcessModule)
    assert isinstance(learner.buffer._storage, LazyTensorStorage) and learner.buffer._storage.max_size == 10_000
    widths = [m.out_features for m in learner.actor.modules() if isinstance(m, torch.nn.Linear)]
    assert widths == [24, 48, 1]
    a = agent.act(env.reset())
    assert a.shape == (1, 1) and 0 <= float(a) <= 1


def test_exploration_noise_restarts_each_episode():
    env, agent = build(resolve_config(seeds=[0], **SMALL))
    col = OnlineCollector(env, agent, 1, progress=False)
    col.run()
    assert int(agent.learners[0].noise["_ou_steps"]) > 1
    agent.act(col.td)  # the first step of the next episode
    assert int(agent.learners[0].noise["_ou_steps"]) == 1


@pytest.mark.parametrize("settings, match", [
    (dict(env="liquidation", action_levels=21), "action_levels=0"),
    (dict(env="square"), "continuous"),
    (dict(env="liquidation", batch_size=200, buffer_size=100), "batch_size"),
])
def test_refused_settings(settings, match):
    with pytest.raises(ValueError, match=match):
        resolve_config(agent="ddpg", **settings)


def test_each_seed_draws_its_own_exploration_noise():
    """The first OU draw of an episode (previous noise 0) is sigma * N(0, 1) from the
    learner's own generator: different for different seeds, and the generators move."""
    env, agent = build(resolve_config(seeds=[0, 1], **SMALL))
    before = [learner.generator_state.clone() for learner in agent.learners]
    agent.act(env.reset())
    noise = [float(learner.noise["_ou_prev_noise"]) for learner in agent.learners]
    assert noise[0] != noise[1]
    assert all(not torch.equal(b, learner.generator_state) for b, learner in zip(before, agent.learners))
