"""The gymnasium family's rules (envs/gym/env.py) one by one: plain data in and out of a
checkpoint for every kind it holds and each refusal's words, the bounds an id's observations are
mapped from, the config an id completes, the first reset's seed, the specs of raw observations, and
what a checkpoint of another env says."""
import math

import gymnasium
import numpy as np
import pytest
import torch
from torchrl.data import Bounded, Unbounded

from trl_dgpq.envs.gym import env as gym_module
from trl_dgpq.envs.gym.env import (GymConfig, _attributes, _layers, from_plain, gym_env, to_plain)
from trl_dgpq.rng import ENV_STREAM, SeedStreams, stream_id


@pytest.mark.parametrize("value", [None, True, 3, 2.5, "text", [1, "a", None], (1, (2.0, "b")),
                                   {"k": 1, 2: [3], (4, 5): None}])
def test_plain_python_comes_back_as_it_was(value):
    assert from_plain(to_plain(value)) == value and type(from_plain(to_plain(value))) is type(value)


def test_numpy_values_come_back_with_their_dtype_and_as_copies():
    for v in (np.float32(1.5), np.int64(-3), np.bool_(True), np.uint8(7)):
        plain = to_plain(v)
        assert plain == {"np": v.item(), "dtype": v.dtype.str}
        back = from_plain(plain)
        assert back == v and back.dtype == v.dtype and type(back) is type(v)
    a = np.arange(6, dtype=np.float32).reshape(2, 3)
    plain = to_plain(a)
    assert isinstance(plain["ndarray"], torch.Tensor) and plain["dtype"] == "<f4"
    a[0, 0] = 99.0                                           # saved, not shared
    back = from_plain(plain)
    assert back.dtype == np.float32 and back.tolist() == [[0.0, 1.0, 2.0], [3.0, 4.0, 5.0]]
    back[0, 1] = -1.0
    assert from_plain(plain)[0, 1] == 1.0
    for dtype in (np.int8, np.uint16, np.bool_, np.float64):
        v = np.ones(3, dtype=dtype)
        assert from_plain(to_plain(v)).dtype == dtype
    text = np.array([["a", "bc"], ["d", "e"]])
    plain = to_plain(text)
    assert plain == {"ndarray_list": [["a", "bc"], ["d", "e"]], "dtype": "<U2", "shape": [2, 2]}
    assert (from_plain(plain) == text).all() and from_plain(plain).dtype == text.dtype
    frozen = np.array([[b"S", b"F"], [b"H", b"G"]])          # FrozenLake's map: bytes, nested in a list
    back = from_plain(to_plain([np.bool_(True), frozen]))
    assert back[0] is np.True_ and back[1].dtype == frozen.dtype and back[1].tolist() == frozen.tolist()
    empty = np.zeros((0, 2), dtype=object)
    assert from_plain(to_plain(empty)).shape == (0, 2)


@pytest.mark.parametrize("bits", ["PCG64", "PCG64DXSM", "MT19937", "Philox", "SFC64"])
def test_a_generator_continues_where_it_was(bits):
    g = np.random.Generator(getattr(np.random, bits)(7))
    g.random(3)
    back = from_plain(to_plain(g))
    assert back is not g and back.random(4).tolist() == g.random(4).tolist()


@pytest.mark.parametrize("plain, words", [
    ({"generator": {"bit_generator": "Evil"}}, "unknown bit generator 'Evil' in a checkpoint"),
    ({}, "not plain data this code wrote: a dict in a gym env's checkpoint state"),
    ({"other": 1}, "not plain data this code wrote: a dict in a gym env's checkpoint state"),
    ({"ndarray": [1, 2], "dtype": "<f8"}, "not plain data this code wrote: a dict in a gym env's checkpoint state"),
    (torch.zeros(2), "not plain data this code wrote: a Tensor in a gym env's checkpoint state"),
    ((1, 2), "not plain data this code wrote: a tuple in a gym env's checkpoint state"),
])
def test_what_this_code_never_writes_is_refused(plain, words):
    with pytest.raises(ValueError) as err:
        from_plain(plain)
    assert str(err.value) == words


def test_what_plain_data_cannot_hold_is_refused():
    with pytest.raises(ValueError) as err:
        to_plain({"k": object()})
    assert str(err.value) == "cannot save a object as plain data"
    with pytest.raises(ValueError, match="cannot save a set"):
        to_plain([{1}])


def test_a_gymnasium_envs_layers_and_their_changing_attributes():
    env = gymnasium.make("CartPole-v1")
    layers = _layers(env)
    assert layers[0] is env and layers[-1] is env.unwrapped and len(layers) >= 2
    assert all(isinstance(layer, gymnasium.Wrapper) for layer in layers[:-1])
    outer = _attributes(layers[0])
    assert "env" not in outer and not any(isinstance(v, gymnasium.spaces.Space) for v in outer.values())
    inner = _attributes(env.unwrapped)
    assert {"gravity", "masscart"} <= set(inner) and "action_space" not in inner and "spec" not in inner
    env.close()


def test_the_bounds_are_the_given_ones_then_the_documented_then_gymnasiums():
    cartpole, car = gym_env("CartPole-v1"), gym_env("MountainCar-v0")
    low, high = cartpole.bounds(GymConfig(obs_low=(-1, -2, -3, -4), obs_high=(1, 2, 3, 4)))
    assert low.tolist() == [-1, -2, -3, -4] and high.tolist() == [1, 2, 3, 4] and low.dtype == torch.float64
    low, high = cartpole.bounds(GymConfig())
    # the episode's ends (x +-2.4, theta +-12 degrees) and the velocities a surviving pole reaches
    assert low.tolist() == pytest.approx([-2.4, -3.0, -12 * math.pi / 180, -3.5], abs=1e-4)
    assert high.tolist() == pytest.approx([2.4, 3.0, 12 * math.pi / 180, 3.5], abs=1e-4)
    low, high = car.bounds(GymConfig())
    assert low.tolist() == pytest.approx([-1.2, -0.07]) and high.tolist() == pytest.approx([0.6, 0.07])


def test_observations_are_mapped_onto_the_unit_box_and_clipped():
    env = gym_env("MountainCar-v0")([0])
    unit = env.to_unit_box(torch.tensor([[-0.3, 0.0], [0.6, -0.07], [2.0, -1.0]], dtype=torch.float32))
    assert unit.dtype == torch.float64
    assert unit.flatten().tolist() == pytest.approx([0.5, 0.5, 1.0, 0.0, 1.0, 0.0], abs=1e-7)
    assert not env.squash.any() and env.offset.tolist() == pytest.approx([-1.2, -0.07])
    env.close()


def test_a_config_is_completed_from_the_registration_and_checked_against_it(monkeypatch):
    assert gym_env("CartPole-v1").checked_config(GymConfig()).max_steps == 500
    assert gym_env("CartPole-v1").checked_config(GymConfig(max_steps=7)).max_steps == 7
    with pytest.raises(ValueError) as err:
        gym_env("CartPole-v1").checked_config(GymConfig(obs_low=(0.0, 0.0), obs_high=(1.0, 1.0)))
    assert str(err.value) == "gym:CartPole-v1 observations have 4 dimensions; obs_low/obs_high have 2"
    monkeypatch.setattr(gym_module, "describe", lambda gym_id: (2, np.zeros(3), np.ones(3), None))
    with pytest.raises(ValueError) as err:
        gym_env("CartPole-v1").checked_config(GymConfig())
    assert str(err.value) == "gym:CartPole-v1 has no registered max_episode_steps: set max_steps"
    assert gym_env("CartPole-v1").checked_config(GymConfig(max_steps=3)).max_steps == 3


@pytest.mark.parametrize("low, high, words", [
    ((0.0,), (), "obs_low and obs_high need one bound per dimension each, got 1 and 0"),
    ((0.0, 1.0), (1.0, 1.0), "need finite obs_low < obs_high, got [0.0, 1.0] and [1.0, 1.0]"),
    ((0.0,), (math.inf,), "need finite obs_low < obs_high, got [0.0] and [inf]"),
    ((-math.inf,), (1.0,), "need finite obs_low < obs_high"),
])
def test_bounds_settings_are_refused_in_words(low, high, words):
    with pytest.raises(ValueError) as err:
        GymConfig(obs_low=low, obs_high=high).cross_check()
    assert str(err.value).startswith(words)


def test_the_first_reset_is_seeded_by_the_seed_and_in_evaluation_by_its_own_stream():
    env = gym_env("CartPole-v1")([5, 6])
    assert env.first_seed(5) == 5
    env.for_evaluation()
    key = stream_id(f"evaluation/{ENV_STREAM}")
    assert env.first_seed(6) == int(SeedStreams([6], key).uniform(1)[0, 0] * 2**32) != 6
    assert 0 <= env.first_seed(5) < 2**32
    env.close()


def test_raw_observations_are_bounded_where_gymnasiums_are_finite():
    car = gym_env("MountainCar-v0").describe(GymConfig(observations="raw"))
    spec = car.observation_spec["observation"]
    assert isinstance(spec, Bounded) and spec.space.low[0].tolist() == pytest.approx([-1.2, -0.07])
    assert spec.dtype == torch.float64
    pole = gym_env("CartPole-v1").describe(GymConfig(observations="raw")).observation_spec["observation"]
    assert isinstance(pole, Unbounded) and pole.shape == (1, 4) and pole.dtype == torch.float64
    unit = gym_env("CartPole-v1").describe().observation_spec["observation"]
    assert unit.space.low.tolist() == [[0.0] * 4] and unit.space.high.tolist() == [[1.0] * 4]
    assert gym_env("Acrobot-v1").describe().num_actions() == 3


def test_a_checkpoint_of_another_env_is_refused_in_words():
    env = gym_env("CartPole-v1")([0, 1])
    env.reset()
    state = env.state_dict()
    with pytest.raises(ValueError) as err:
        env.load_state_dict({**state, "gym": None})
    assert str(err.value) == ("gym:CartPole-v1 cannot continue from a checkpoint: only gymnasium's classic_control "
                              "and toy_text envs keep all their state in Python attributes; start the run again")
    layers = len(state["gym"][0])
    with pytest.raises(ValueError) as err:
        env.load_state_dict({**state, "gym": [state["gym"][0][:-1], state["gym"][1]]})
    assert str(err.value) == ("gym:CartPole-v1: the checkpoint's env state is not this env's "
                              f"({layers} layers of plain data)")
    with pytest.raises(ValueError, match="layers of plain data"):
        env.load_state_dict({**state, "gym": ["not a list", state["gym"][1]]})
    env.close()


def test_each_ids_class_is_made_once_with_its_name():
    cls = gym_env("CartPole-v1")
    assert cls is gym_env("CartPole-v1") and cls.__name__ == "Gym[CartPole-v1]" and cls.gym_id == "CartPole-v1"
    assert cls.__module__ == "trl_dgpq.envs.gym.env" and issubclass(cls, gym_module.GymSeedEnv)


def test_a_wrappers_own_state_is_kept_and_its_link_inward_is_not():
    env = gymnasium.make("CartPole-v1", max_episode_steps=9)
    limit = next(layer for layer in _layers(env) if isinstance(layer, gymnasium.wrappers.TimeLimit))
    kept = _attributes(limit)
    assert kept["_max_episode_steps"] == 9 and "_elapsed_steps" in kept and "env" not in kept
    env.close()


def test_a_text_arrays_declared_width_comes_back():
    wide = np.array(["a", "bc"], dtype="<U5")
    back = from_plain(to_plain(wide))
    assert back.dtype == np.dtype("<U5") and back.tolist() == ["a", "bc"]


def test_the_envs_own_cap_is_gymnasiums_time_limit_and_its_config_is_kept():
    env = gym_env("MountainCar-v0")([0, 1], cfg=GymConfig(max_steps=9))
    assert env.cfg.max_steps == 9 and env.max_steps == 9
    limits = [layer for layer in _layers(env.envs[0]._env) if isinstance(layer, gymnasium.wrappers.TimeLimit)]
    assert [layer._max_episode_steps for layer in limits] == [9]
    assert env.started.dtype == torch.bool and env.started.tolist() == [False, False]
    env.close()


def test_a_half_bounded_dimension_is_squashed_and_its_raw_spec_unbounded(monkeypatch):
    monkeypatch.setattr(gym_module, "describe", lambda gym_id: (3, np.array([-1.2, -0.07]), np.array([np.inf, 0.07]),
                                                                200))
    cls = gym_env.__wrapped__("MountainCar-v0")
    env = cls([0])
    assert env.squash.tolist() == [True, False]
    assert env.to_unit_box(torch.tensor([[0.0, 0.035]]))[0].tolist() == pytest.approx([0.5, 0.75])
    env.close()
    assert isinstance(cls.describe(GymConfig(observations="raw")).observation_spec["observation"], Unbounded)


def test_raw_observations_handed_out_do_not_change_with_the_next_step():
    env = gym_env("CartPole-v1")([0], observations="raw")
    first = env.reset()["observation"].clone()
    handed = env._initial(torch.tensor([False]))["observation"]
    env._transition(torch.tensor([1]))
    assert torch.equal(handed, first) and not torch.equal(env.raw, first)
    env.close()


def test_closing_twice_is_allowed_when_asked():
    env = gym_env("CartPole-v1")([0, 1])
    env.close()
    assert env.is_closed and all(seed_env.is_closed for seed_env in env.envs)       # each seed's gymnasium env
    env.close(raise_if_closed=False)


def test_every_spec_is_made_on_the_envs_device():
    with torch.device("meta"):
        infos = [gym_env("CartPole-v1").describe(device="cpu"),
                 gym_env("CartPole-v1").describe(GymConfig(observations="raw"), device="cpu")]
    specs = [s for info in infos for s in (info.observation_spec, info.observation_spec["observation"], info.action_spec)]
    assert {spec.device.type for spec in specs} == {"cpu"}


class ThirdsEnv(gymnasium.Env):
    """Rewards and observations float32 cannot hold, as numpy float64: 0.1 + action, and thirds
    (its space says float32, as many envs' do while they return float64 arrays), its observation a
    reversed view."""
    observation_space = gymnasium.spaces.Box(0.0, 1.0, (2,), np.float32)
    action_space = gymnasium.spaces.Discrete(2)

    def __init__(self, **kwargs):  # TorchRL's GymEnv passes frameskip=1
        self.t = 0

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        self.t = 0
        return np.array([0.0, 1 / 3]), {}

    def step(self, action):
        self.t += 1
        flipped = np.array([1 / 3, self.t / 3])[::-1]  # a view with a negative stride, as some envs return
        return flipped, np.float64(0.1 + action), self.t == 3, False, {}


def test_a_step_converts_as_torchrls_gymenv_reward_float32_observation_its_spaces_dtype():
    """Each seed is stepped through gymnasium's own step with GymEnv's conversions: the reward to
    its spec's float32 (0.1 becomes 0.100000001...), the observation to its space's float32 (a
    third as float32 holds it), terminated where the env says, never truncated."""
    gymnasium.register("ThirdsTest-v0", entry_point=ThirdsEnv, max_episode_steps=50)
    try:
        env = gym_env("ThirdsTest-v0")([0, 1], observations="raw")
        td = env.reset()
        for t in (1, 2, 3):
            td["action"] = torch.tensor([0, 1])
            out, td = env.step_and_maybe_reset(td)
            nxt = out["next"]
            assert nxt["reward"][:, 0].tolist() == [float(np.float32(0.1)), float(np.float32(1.1))]
            assert nxt["observation"].tolist() == [[float(np.float32(t / 3)), float(np.float32(1 / 3))]] * 2
            assert nxt["terminated"].flatten().tolist() == [t == 3] * 2 and not nxt["truncated"].any()
        env.close()
    finally:
        gymnasium.registry.pop("ThirdsTest-v0")
