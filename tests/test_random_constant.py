"""The two agents without learning (trl_dgpq/agents/random.py and constant.py), rule by rule: the
random agent's actions from each seed's own policy stream by hand, its state; the constant agent's
action by index or by name, and every refusal in its words."""
import pytest
import torch
from torchrl.data import Categorical, Composite, Unbounded

from trl_dgpq.agents.constant import ConstantAgent, ConstantConfig
from trl_dgpq.agents.random import RandomAgent, RandomConfig
from trl_dgpq.envs.base import EnvInfo
from trl_dgpq.envs.corridor.env import CorridorEnv
from trl_dgpq.envs.liquidation.env import LiquidationEnv
from trl_dgpq.envs.square.env import SquareEnv
from trl_dgpq.rng import POLICY_STREAM, SeedStreams

SQUARE = SquareEnv.describe()          # "north", "south", "east", "west"
CORRIDOR = CorridorEnv.describe()      # "left", "right"
CONTINUOUS = LiquidationEnv.describe()
UNNAMED = EnvInfo(None, Composite(observation=Unbounded(shape=(1, 2))), Categorical(3, shape=(1,)))


def test_random_actions_are_each_seeds_policy_stream_scaled_to_the_actions():
    seeds = (3, 11, 40)
    agent = RandomAgent.make(RandomConfig(), SQUARE, seeds)
    mine = SeedStreams(seeds, POLICY_STREAM)
    for _ in range(5):
        action = agent.act(None)
        assert action.dtype == torch.long and action.shape == (3,)
        assert action.tolist() == (mine.uniform(1)[:, 0] * 4).floor().long().tolist()
    assert agent.num_actions == 4 and RandomAgent(seeds, 7).num_actions == 7


def test_random_actions_cover_every_action_and_no_other():
    actions = torch.cat([RandomAgent(range(50), 3).act(None) for _ in range(2)])
    assert set(actions.tolist()) == {0, 1, 2}


def test_the_random_agents_state_round_trips_and_it_neither_learns_nor_keeps_stats():
    agent = RandomAgent([1, 2], 4)
    agent.act(None), agent.act(None)
    state = agent.state_dict()
    assert state["rng"]["counter"] == 2
    other = RandomAgent([1, 2], 4)
    other.load_state_dict(state)
    assert torch.equal(other.act(None), agent.act(None))
    assert agent.observe(None) is None and agent.episode_stats() == {}
    assert RandomAgent.memory_bytes(RandomConfig(), SQUARE, 100) == 0
    with pytest.raises(ValueError, match="other seeds"):
        RandomAgent([1, 3], 4).load_state_dict(state)


def test_the_random_agent_refuses_continuous_actions_naming_itself():
    assert RandomAgent.resolve_config(cfg := RandomConfig(), SQUARE) is cfg
    for call in (lambda: RandomAgent.resolve_config(RandomConfig(), CONTINUOUS),
                 lambda: RandomAgent.make(RandomConfig(), CONTINUOUS, [0])):
        with pytest.raises(ValueError, match=r"^random needs discrete actions"):
            call()


def test_the_random_agent_draws_on_the_envs_device():
    with torch.device("meta"):
        agent = RandomAgent.make(RandomConfig(), SquareEnv.describe(device="cpu"), [0, 1])
    assert agent.rng.key.device.type == "cpu" and agent.act(None).device.type == "cpu"


@pytest.mark.parametrize("info, action, index", [(SQUARE, "3", 3), (SQUARE, "0", 0), (SQUARE, "west", 3),
                                                 (UNNAMED, "2", 2), (CORRIDOR, "right", 1),
                                                 (CORRIDOR, "left", 0), (CORRIDOR, "1", 1)])
def test_the_constant_action_is_its_index_or_its_name(info, action, index):
    cfg = ConstantConfig(action=action)
    assert ConstantAgent.index(cfg, info) == index
    assert ConstantAgent.resolve_config(cfg, info) is cfg
    agent = ConstantAgent.make(cfg, info, [5, 6, 7])
    for _ in range(2):
        out = agent.act(None)
        assert out.tolist() == [index] * 3 and out.dtype == torch.long


def test_the_constant_agents_default_is_action_zero():
    assert ConstantConfig().action == "0"
    assert ConstantAgent.make(ConstantConfig(), SQUARE, [0]).act(None).tolist() == [0]


@pytest.mark.parametrize("info, action, words", [
    (SQUARE, "4", r"^action 4 is not among this env's 4 actions$"),
    (CORRIDOR, "2", r"^action 2 is not among this env's 2 actions$"),
    (CORRIDOR, "up", r"^this env has no action 'up'"),
    (UNNAMED, "north", r"^this env does not name its actions: give an index instead of 'north'$"),
    (SQUARE, "-1", r"^this env has no action '-1'"),
    (UNNAMED, "3", r"^action 3 is not among this env's 3 actions$"),
    (CONTINUOUS, "0", r"^constant needs discrete actions"),
])
def test_the_constant_agent_refuses_an_action_the_env_lacks(info, action, words):
    for call in (ConstantAgent.resolve_config, lambda cfg, info: ConstantAgent.make(cfg, info, [0])):
        with pytest.raises(ValueError, match=words):
            call(ConstantConfig(action=action), info)


def test_the_constant_agent_acts_on_the_envs_device():
    with torch.device("meta"):
        agent = ConstantAgent.make(ConstantConfig("1"), CorridorEnv.describe(device="cpu"), [0, 1])
    assert agent.act(None).device.type == "cpu"
