"""The seed-batched env base (envs/base.py) and the corridor (envs/corridor/env.py), rule by
rule: what ``EnvInfo`` tells an agent, partial resets, the step cap and an env's own cap
(truncation, never termination), every action refusal, the streams keyed per seed and apart in
evaluation, and the state's round trip. The numbers are made by hand from ``SeedStreams``."""
from dataclasses import dataclass

import pytest
import torch
from torchrl.data import Bounded, Categorical, Composite, Unbounded

from trl_dgpq.config import setting
from trl_dgpq.envs.base import EnvInfo, SeedBatchedEnv
from trl_dgpq.envs.corridor.env import CorridorConfig, CorridorEnv
from trl_dgpq.rng import ENV_STREAM, SeedStreams, stream_id

EXTRA = stream_id("test.extra")


@dataclass
class ToyConfig:
    max_steps: int = setting(3, "step cap", within="[1, inf)")
    cap: int = setting(0, "the env's own cap: truncate once the position passes it (0: none)", within="[0, inf)")
    reach: float = setting(2.0, "the action box's upper face", within="(0, inf)")


class Toy(SeedBatchedEnv):
    """A position moved by a continuous action in [-1, 2] (two coordinates), an extra stream,
    terminated once the position's first coordinate passes 5."""
    Config = ToyConfig
    action_hint = "use toy-discrete"
    _state_names = ("pos",)
    _streams = (("extra_rng", EXTRA),)

    def __init__(self, seeds=(0,), cfg=None, device="cpu", **overrides):
        super().__init__(seeds, cfg, device, **overrides)
        self.pos = torch.zeros(self.num_seeds, 2, dtype=torch.float64, device=self.device)

    @classmethod
    def _specs(cls, cfg, S, device):
        observation = Composite(observation=Bounded(torch.tensor([-1.0, 0.0], device=device).expand(S, 2),
                                                    torch.tensor([4.0, 2.0], device=device).expand(S, 2), shape=(S, 2),
                                                    dtype=torch.float64, device=device),
                                extra=Unbounded(shape=(S,), dtype=torch.float64, device=device),
                                shape=(S,), device=device)
        action = Bounded(-1.0, cfg.reach, shape=(S, 2), dtype=torch.float64, device=device)
        return observation, action, Unbounded(shape=(S, 1), dtype=torch.float64, device=device)

    def _observe(self):
        return self._td(observation=self.pos.clone(), extra=self.pos[:, 1].clone())

    def _initial(self, mask):
        self.pos[mask] = 0.0
        return self._observe()

    def _transition(self, action):
        self.pos += action
        terminated = self.pos[:, 0] > 5
        reward = self.pos.sum(1)
        if self.cfg.cap:
            return self._observe(), reward, terminated, self.pos[:, 0] > self.cfg.cap
        return self._observe(), reward, terminated


def act(env, action):
    td = env._td(observation=torch.zeros(env.num_seeds, 1), action=action)
    return env.step(td)["next"]


# ------------------------------------------------------------------ EnvInfo
def test_env_info_tells_an_agent_the_specs_keys_and_actions_from_the_config_alone():
    info = CorridorEnv.describe(CorridorConfig(length=4))
    assert info.config.length == 4 and info.observation_dim == 1 and info.keys == ()
    assert info.num_actions() == 2 and info.action_names == ("left", "right")
    assert info.action_index("left") == 0 and info.action_index("right") == 1
    assert info.state_box() == ([0.0], [1.0]) and info.device == torch.device("cpu")
    assert info.observation_spec["observation"].shape == (1, 1)          # one seed's
    toy = Toy.describe()
    assert toy.config == ToyConfig() and toy.keys == ("extra",) and toy.observation_dim == 2
    assert toy.state_box() == ([-1.0, 0.0], [4.0, 2.0])
    assert toy.action_box().space.high.tolist() == [[2.0, 2.0]] and toy.action_hint == "use toy-discrete"
    assert Toy(seeds=(0, 1), max_steps=7).info.config.max_steps == 7
    assert Toy.describe(ToyConfig(reach=3.0)).action_box().space.high.tolist() == [[3.0, 3.0]]   # from the config


def test_env_info_refuses_the_other_kind_of_action_naming_who_asks_and_the_hint():
    with pytest.raises(ValueError, match=r"^dqn needs discrete actions; this env's action spec is "
                                         r"BoundedContinuous \(use toy-discrete\)$"):
        Toy.describe().num_actions("dqn")
    with pytest.raises(ValueError, match=r"^this agent needs a continuous \(Bounded\) action spec; this env's is "
                                         r"Categorical$"):
        CorridorEnv.describe().action_box()
    with pytest.raises(ValueError, match=r"^ddpg needs a continuous \(Bounded\) action spec; this env's is Categorical"):
        CorridorEnv.describe().action_box("ddpg")
    with pytest.raises(ValueError, match=r"^this agent needs discrete actions; this env's action spec is "
                                         r"BoundedContinuous \(use toy-discrete\)$"):
        Toy.describe().num_actions()
    observation = Composite(observation=Unbounded(shape=(1, 2)))
    with pytest.raises(ValueError, match=r"^dqn needs discrete actions; this env's action spec is BoundedContinuous$"):
        EnvInfo(None, observation, Bounded(0.0, 1.0, shape=(1, 1))).num_actions("dqn")       # no hint: none shown
    with pytest.raises(ValueError, match=r"^ddpg needs a continuous \(Bounded\) action spec; this env's is Categorical "
                                         r"\(try the box\)$"):
        EnvInfo(None, observation, Categorical(2, shape=(1,)), action_hint="try the box").action_box("ddpg")


def test_action_names_are_looked_up_and_refused_in_words():
    with pytest.raises(ValueError, match=r"^this env does not name its actions: give an index instead of 'up'$"):
        Toy.describe().action_index("up")
    with pytest.raises(ValueError, match=r"^this env has no action 'up'; its actions are \['left', 'right'\]$"):
        CorridorEnv.describe().action_index("up")


def test_an_unbounded_observation_has_no_state_box():
    info = EnvInfo(None, Composite(observation=Unbounded(shape=(1, 2))), None)
    assert info.action_names == () and info.action_hint == "" and info.device == "cpu"
    with pytest.raises(ValueError, match=r"^this env's observations are unbounded, so Section 5 has no covering "
                                         r"number from them: use covering unit-square, or give sigma_tol2 and eps1$"):
        info.state_box()


# ------------------------------------------------------------------ making
def test_seeds_settings_and_specs_of_a_made_env():
    env = Toy(seeds=[3, 5, 8], cfg=ToyConfig(max_steps=9), cap=4)
    assert env.seeds == [3, 5, 8] and env.num_seeds == 3 and env.batch_size == (3,)
    assert env.cfg == ToyConfig(max_steps=9, cap=4) and env.max_steps == 9
    assert env.t.tolist() == [0, 0, 0] and env.t.dtype == torch.long
    assert env.action_spec.shape == (3, 2) and env.observation_spec["observation"].shape == (3, 2)
    done = env.full_done_spec
    assert set(done.keys()) == {"done", "terminated", "truncated"}
    assert all(done[k].shape == (3, 1) and done[k].dtype == torch.bool and done[k].space.n == 2 for k in done.keys())
    assert Toy().seeds == [0] and Toy().cfg == ToyConfig()
    assert Toy(seeds=(torch.tensor(2),)).seeds == [2] and type(Toy(seeds=(2.0,)).seeds[0]) is int


@pytest.mark.parametrize("seeds", [(), (1, -1)])
def test_no_seed_or_a_negative_one_is_refused(seeds):
    with pytest.raises(ValueError, match=r"^need at least one seed, each a non-negative integer$"):
        Toy(seeds=seeds)


def test_a_config_is_checked_when_an_env_is_made_and_described():
    with pytest.raises(ValueError, match="max_steps"):
        Toy(max_steps=0)
    with pytest.raises(ValueError, match="slip"):
        CorridorEnv.describe(CorridorConfig(slip=0.5))


# ------------------------------------------------------------------ reset and step
def test_a_partial_reset_resets_only_the_masked_seeds_and_their_step_counts():
    env = Toy(seeds=(0, 1, 2), max_steps=10)
    first = env.reset()
    assert first["observation"].tolist() == [[0.0, 0.0]] * 3
    assert {first[k].tolist() == [[False]] * 3 for k in ("done", "terminated", "truncated")} == {True}
    act(env, torch.ones(3, 2, dtype=torch.float64))
    act(env, torch.ones(3, 2, dtype=torch.float64))
    assert env.t.tolist() == [2, 2, 2]
    out = env._reset(env._td(_reset=torch.tensor([[False], [True], [False]])))
    assert env.t.tolist() == [2, 0, 2] and env.pos.tolist() == [[2.0, 2.0], [0.0, 0.0], [2.0, 2.0]]
    assert out["observation"].tolist() == [[2.0, 2.0], [0.0, 0.0], [2.0, 2.0]]
    for key in ("done", "terminated", "truncated"):
        assert out[key].shape == (3, 1) and out[key].dtype == torch.bool and not out[key].any()
    env._reset(env._td())                               # no mask: every seed
    assert env.t.tolist() == [0, 0, 0] and env.pos.abs().sum() == 0


def test_the_step_cap_truncates_and_termination_is_not_truncation():
    env = Toy(seeds=(0, 1), max_steps=3)
    env.reset()
    go = torch.tensor([[2.0, 0.0], [1.0, 0.0]], dtype=torch.float64)
    for _ in range(2):
        out = act(env, go)
        assert not out["done"].any()
    assert out["reward"].tolist() == [[4.0], [2.0]] and out["reward"].shape == (2, 1)
    out = act(env, go)                     # step 3: seed 0 passes 5 (terminated), seed 1 hits the cap
    assert out["terminated"][:, 0].tolist() == [True, False]
    assert out["truncated"][:, 0].tolist() == [False, True]
    assert out["done"][:, 0].tolist() == [True, True]
    assert env.t.tolist() == [3, 3]
    env.t.zero_()
    own = env._step(env._td(action=go))                 # the env's own output, before TorchRL's completion
    assert {k: own[k][:, 0].tolist() for k in ("terminated", "truncated", "done")} == {
        "terminated": [True, False], "truncated": [False, False], "done": [True, False]}


def test_an_envs_own_cap_truncates_before_the_step_cap_unless_it_terminates():
    env = Toy(seeds=(0, 1, 2), max_steps=100, cap=3)
    env.reset()
    out = act(env, torch.tensor([[2.0, 0.0], [1.0, 0.0], [2.0, 0.0]], dtype=torch.float64))
    assert not out["done"].any()
    env.pos[2, 0] = 4.0
    out = act(env, torch.tensor([[2.0, 0.0], [1.0, 0.0], [2.0, 0.0]], dtype=torch.float64))
    assert out["truncated"][:, 0].tolist() == [True, False, False]      # 4 > 3; seed 2 terminated at 6
    assert out["terminated"][:, 0].tolist() == [False, False, True]
    assert out["done"][:, 0].tolist() == [True, False, True]


# ------------------------------------------------------------------ actions
def test_discrete_actions_are_indices_and_integral_floats_are_cast():
    env = CorridorEnv(seeds=(0, 1), slip=0.0)
    env.reset()
    assert env.check_action(torch.tensor([1.0, 0.0])).tolist() == [1, 0]
    assert env.check_action(torch.tensor([1.0, 0.0])).dtype == torch.long
    assert env.check_action(torch.tensor([1, 0], dtype=torch.int32)).dtype == torch.long
    assert act(env, torch.tensor([1.0, 1.0]))["observation"][:, 0].tolist() == [1 / 9, 1 / 9]


@pytest.mark.parametrize("action, words", [
    ([1, 0], r"^action must be a tensor of shape \(2,\), got list$"),
    (torch.tensor([[0.0, 1.0], [1.0, 0.0]]), r"^action must be indices of shape \(2,\) in \[0, 2\), got shape \(2, 2\) "
                                             r"\(one-hot\? pass \.argmax\(-1\)\)$"),
    (torch.tensor([0, 1, 1]), r"^action must be indices of shape \(2,\) in \[0, 2\), got shape \(3,\)$"),
    (torch.tensor([True, False]), r"^action must be integer indices in \[0, 2\), got dtype torch\.bool$"),
    (torch.tensor([1 + 0j, 0j]), r"^action must be integer indices in \[0, 2\), got dtype torch\.complex64$"),
    (torch.tensor([0.5, 1.0]), r"^action must be integer indices in \[0, 2\), got non-integral \[0\.5\]$"),
    (torch.tensor([float("nan"), float("inf")]), r"got non-integral \[nan, inf\]$"),
    (torch.tensor([-1, 2]), r"^action must be in \[0, 2\), got \[-1, 2\]$"),
    (torch.tensor([-1.0, 1.0]), r"^action must be in \[0, 2\), got \[-1\]$"),
])
def test_bad_discrete_actions_are_refused_in_words(action, words):
    with pytest.raises(ValueError, match=words):
        CorridorEnv(seeds=(0, 1)).check_action(action)


def test_only_the_first_three_bad_actions_are_shown():
    with pytest.raises(ValueError, match=r"got \[5, 6, 7\]$"):
        CorridorEnv(seeds=range(5)).check_action(torch.tensor([0, 5, 6, 7, 8]))
    with pytest.raises(ValueError, match=r"got non-integral \[0\.5, 1\.5, 2\.5\]$"):
        CorridorEnv(seeds=range(4)).check_action(torch.tensor([0.5, 1.5, 2.5, 3.5]))
    with pytest.raises(ValueError, match=r"got \[3\.0, 4\.0, 5\.0\]$"):
        Toy(seeds=range(2)).check_action(torch.tensor([[3.0, 4.0], [5.0, 6.0]]))


def test_continuous_actions_in_the_box_pass_at_its_faces_cast_to_the_specs_dtype():
    env = Toy(seeds=(0, 1))
    action = env.check_action(torch.tensor([[-1.0, 2.0], [0.5, 0.0]], dtype=torch.float32))
    assert action.dtype == torch.float64 and action.tolist() == [[-1.0, 2.0], [0.5, 0.0]]


@pytest.mark.parametrize("action, words", [
    (torch.zeros(2), r"^action must have shape \(2, 2\), got \(2,\)$"),
    (torch.tensor([[0.0, 2.5], [-1.5, 0.0]]), r"^action must be finite and in \[-1\.0, 2\.0\], got \[2\.5, -1\.5\]$"),
    (torch.tensor([[0.0, float("nan")], [float("inf"), 0.0]]), r"got \[nan, inf\]$"),
])
def test_bad_continuous_actions_are_refused_in_words(action, words):
    with pytest.raises(ValueError, match=words):
        Toy(seeds=(0, 1)).check_action(action)


def test_an_action_spec_of_another_kind_is_passed_as_it_is():
    env = Toy(seeds=(0,))
    env.action_spec = Unbounded(shape=(1, 2), dtype=torch.float64)
    action = torch.tensor([[9.0, -9.0]], dtype=torch.float32)
    assert env.check_action(action) is action


# ------------------------------------------------------------------ streams
def test_each_stream_is_keyed_by_its_seeds_and_id_and_apart_in_evaluation():
    env = Toy(seeds=(4, 7))
    assert torch.equal(env.rng.uniform(3), SeedStreams([4, 7], ENV_STREAM).uniform(3))
    assert torch.equal(env.extra_rng.uniform(3), SeedStreams([4, 7], EXTRA).uniform(3))
    assert env.stream_key(ENV_STREAM) == ENV_STREAM and not env.evaluating
    assert env.for_evaluation() is env and env.evaluating
    assert env.stream_key(ENV_STREAM) == stream_id(f"evaluation/{ENV_STREAM}")
    assert torch.equal(env.rng.uniform(2), SeedStreams([4, 7], stream_id(f"evaluation/{ENV_STREAM}")).uniform(2))
    assert torch.equal(env.extra_rng.uniform(2), SeedStreams([4, 7], stream_id(f"evaluation/{EXTRA}")).uniform(2))
    assert not Toy(seeds=(4, 7)).evaluating          # one env's evaluation is not another's


def test_set_seed_rekeys_the_streams_as_seed_seed_plus_one_and_none_keeps_them():
    env = Toy(seeds=(0, 0, 0))
    env.set_seed(10)
    assert env.seeds == [10, 11, 12]
    assert torch.equal(env.rng.uniform(1), SeedStreams([10, 11, 12], ENV_STREAM).uniform(1))
    assert torch.equal(env.extra_rng.uniform(1), SeedStreams([10, 11, 12], EXTRA).uniform(1))
    env._set_seed(None)
    assert env.seeds == [10, 11, 12] and env.rng.counter == 1


def test_the_corridor_slips_from_its_seeds_own_stream():
    seeds, slip = (2, 6, 9), 0.4
    env = CorridorEnv(seeds=seeds, slip=slip, length=5)
    env.reset()
    mine = SeedStreams(seeds, ENV_STREAM)
    cell = torch.zeros(3)
    for action in ([1, 1, 0], [1, 0, 1], [1, 1, 1]):
        slipped = mine.uniform(1)[:, 0] < slip
        cell = (cell + torch.where((torch.tensor(action) == 1) ^ slipped, 1.0, -1.0)).clamp(0, 4)
        out = act(env, torch.tensor(action))
        assert out["observation"][:, 0].tolist() == (cell / 4).double().tolist()
        assert out["observation"].dtype == torch.float64 and out["reward"].dtype == torch.float64


def test_the_corridor_ends_in_its_last_cell_with_reward_zero_and_minus_one_before():
    env = CorridorEnv(seeds=(0, 1), slip=0.0, length=3, max_steps=50)
    env.reset()
    out = act(env, torch.tensor([1, 0]))
    assert out["reward"][:, 0].tolist() == [-1.0, -1.0] and out["observation"][:, 0].tolist() == [0.5, 0.0]
    out = act(env, torch.tensor([1, 1]))
    assert out["terminated"][:, 0].tolist() == [True, False] and out["reward"][:, 0].tolist() == [0.0, -1.0]
    assert out["observation"][:, 0].tolist() == [1.0, 0.5] and env.cell.tolist() == [2, 1]
    env.cell[1] = 2
    assert act(env, torch.tensor([0, 0]))["observation"][:, 0].tolist() == [0.5, 0.5]      # left: one cell
    env.cell[:] = torch.tensor([2, 0])
    assert act(env, torch.tensor([1, 0]))["observation"][:, 0].tolist() == [1.0, 0.0]   # walls at both ends
    env.reset(env._td(_reset=torch.tensor([True, False])))
    assert env.cell.tolist() == [0, 0] and env.t.tolist() == [0, 4]


def test_the_corridor_is_made_from_its_config_with_long_cells_and_float64_specs():
    env = CorridorEnv(seeds=(0,), cfg=CorridorConfig(length=4, slip=0.0))
    assert env.cfg.length == 4 and env.cell.dtype == torch.long and env.state_dict()["cell"].dtype == torch.long
    assert env.observation_spec["observation"].dtype == env.reward_spec.dtype == torch.float64
    assert act(env, torch.tensor([1]))["observation"].tolist() == [[1 / 3]]


def test_the_corridors_config_defaults():
    assert (CorridorConfig().length, CorridorConfig().slip, CorridorConfig().max_steps) == (10, 0.1, 50)


# ------------------------------------------------------------------ state
def test_the_state_round_trips_exactly_and_the_env_continues_the_same():
    env = Toy(seeds=(1, 2), max_steps=50)
    env.reset()
    act(env, torch.full((2, 2), 0.5, dtype=torch.float64))
    env.rng.uniform(2), env.extra_rng.uniform(1), env.extra_rng.uniform(1)
    state = env.state_dict()
    assert set(state) == {"t", "rng", "extra_rng", "pos"}
    assert state["t"].tolist() == [1, 1] and state["pos"].tolist() == [[0.5, 0.5]] * 2
    assert state["rng"]["counter"] == 1 and state["extra_rng"]["counter"] == 2
    state["pos"].add_(1)                 # the state is a copy, not the env's own tensors
    state["t"].add_(1)
    assert env.pos.tolist() == [[0.5, 0.5]] * 2 and env.t.tolist() == [1, 1]
    state = env.state_dict()
    other = Toy(seeds=(1, 2), max_steps=50)
    other.load_state_dict(state)
    assert other.t.tolist() == [1, 1] and other.pos.tolist() == [[0.5, 0.5]] * 2
    assert torch.equal(other.rng.uniform(2), env.rng.uniform(2))
    assert torch.equal(other.extra_rng.uniform(1), env.extra_rng.uniform(1))


def test_a_state_without_a_later_stream_loads_with_that_stream_fresh():
    env = Toy(seeds=(1, 2))
    state = env.state_dict()
    del state["extra_rng"]
    other = Toy(seeds=(1, 2))
    other.extra_rng.uniform(1)
    other.load_state_dict(state)
    assert other.extra_rng.counter == 1           # left as it was: the old run had drawn nothing


def test_a_state_of_other_seeds_is_refused():
    with pytest.raises(ValueError, match=r"^env state is for 3 seeds, this env has 2$"):
        Toy(seeds=(1, 2)).load_state_dict(Toy(seeds=(1, 2, 3)).state_dict())
    with pytest.raises(ValueError, match="other seeds"):
        Toy(seeds=(1, 2)).load_state_dict(Toy(seeds=(1, 3)).state_dict())


def test_every_tensor_is_made_on_the_envs_device():
    """Made with torch's default device set to ``meta``: a tensor made without ``device=`` lands there."""
    with torch.device("meta"):
        env = CorridorEnv(seeds=(0, 1), device="cpu")
        first = env._reset(None)
        env.load_state_dict(env.state_dict())
        info = CorridorEnv.describe(device="cpu")
        toy = Toy.describe(device="cpu")
    out = act(env, torch.tensor([1, 1]))
    assert first.device.type == "cpu" and env.full_done_spec.device.type == "cpu"
    assert {first[k].device.type for k in ("observation", "done", "terminated", "truncated")} == {"cpu"}
    assert {spec.device.type for spec in (info.observation_spec, info.observation_spec["observation"], info.action_spec,
                                          toy.action_spec)} == {"cpu"}
    assert {t.device.type for t in (env.t, env.cell, out["observation"], out["done"], env.rng.key)} == {"cpu"}
    assert {spec.device.type for spec in env.full_done_spec.values()} == {"cpu"}
