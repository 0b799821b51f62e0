"""Gymnasium envs through TorchRL's GymEnv, batched over seeds (envs/gym/)."""
import math

import gymnasium
import numpy as np
import pandas as pd
import pytest
import torch
from torchrl.envs.utils import check_env_specs

from trl_dgpq.collectors.experiment import TIMING_COLUMNS, resolve_config, run_experiment
from trl_dgpq.envs import domain, env_class, make_env
from trl_dgpq.envs.push.gym_adapter import GYM_ID

GYM_ENVS = domain("gym:CartPole-v1").examples()  # the ids with presets


@pytest.mark.parametrize("name", GYM_ENVS)
def test_specs_hold_through_our_wrapper(name):
    env = make_env(name, None, [0, 5])
    check_env_specs(env, seed=None)
    roll = env.rollout(60, break_when_any_done=False)
    obs = roll["next", "observation"]
    assert obs.dtype == torch.float64 and obs.min() >= 0 and obs.max() <= 1
    env.close()


def raw_trajectory(gym_id, seed, actions):
    """Plain gymnasium: observations, rewards and terminations for the action list."""
    env = gymnasium.make(gym_id)
    obs, _ = env.reset(seed=seed)
    out = [obs]
    rewards, terms = [], []
    for a in actions:
        obs, r, term, trunc, _ = env.step(a)
        rewards.append(r)
        terms.append(term)
        if term or trunc:
            obs, _ = env.reset()
        out.append(obs)
    return np.array(out), np.array(rewards), np.array(terms)


def test_cartpole_equals_plain_gymnasium_mapped_to_the_unit_box():
    """Seed 7's observations are gymnasium's reset(seed=7) trajectory through x -> (x - low) / (high - low)
    with the documented bounds (x +-2.4, x' +-3, theta +-0.2095, theta' +-3.5), clipped; rewards 1 and the
    terminations are gymnasium's, across an episode's end (later resets continue the seed's stream)."""
    actions = [(t // 3) % 2 for t in range(80)]
    raw, rewards, terms = raw_trajectory("CartPole-v1", 7, actions)
    assert terms.sum() >= 2
    env = make_env("gym:CartPole-v1", None, [3, 7])
    td = env.reset()
    low, high = np.array([-2.4, -3.0, -0.2095, -3.5]), np.array([2.4, 3.0, 0.2095, 3.5])
    for t, a in enumerate(actions):
        expect = np.clip((raw[t] - low) / (high - low), 0, 1)
        np.testing.assert_allclose(td["observation"][1].numpy(), expect, rtol=0, atol=1e-6)
        td["action"] = torch.tensor([0, a])
        out, td = env.step_and_maybe_reset(td)
        assert out["next", "reward"][1].item() == rewards[t]
        assert out["next", "terminated"][1].item() == terms[t]
    env.close()


@pytest.mark.parametrize("gym_id", ["CartPole-v1", "MountainCar-v0"])
def test_raw_observations_are_gymnasiums_own(gym_id):
    """observations="raw": seed 7's observations are gymnasium's reset(seed=7) trajectory itself
    (no map onto the unit box, no clipping), across
    an episode's end; the spec holds them (CartPole: unbounded, MountainCar: gymnasium's box)."""
    actions = [(t // 3) % 2 * (2 if gym_id == "MountainCar-v0" else 1) for t in range(80)]
    raw, _, terms = raw_trajectory(gym_id, 7, actions)
    check_env_specs(env_class(f"gym:{gym_id}")([3, 7], observations="raw"), seed=None)
    env = env_class(f"gym:{gym_id}")([3, 7], observations="raw")
    td = env.reset()
    for t, a in enumerate(actions):
        np.testing.assert_array_equal(td["observation"][1].numpy(), raw[t].astype(np.float64))
        td["action"] = torch.tensor([0, a])
        _, td = env.step_and_maybe_reset(td)
    assert (raw < 0).any() and (gym_id != "CartPole-v1" or terms.sum() >= 2)  # not the unit box; episodes end
    env.close()


def test_neural_agents_see_raw_observations_dgpq_the_unit_box():
    """The gym presets: DQN on raw observations (its own presets and an id without any), DGPQ on
    the unit box; the choice is recorded in the run's config."""
    for gym_id in [*GYM_ENVS, "gym:CartPole-v0"]:
        assert resolve_config(env=gym_id, agent="dqn")["env"]["observations"] == "raw", gym_id
        assert resolve_config(env=gym_id, agent="dgpq")["env"]["observations"] == "unit", gym_id
    assert resolve_config(env="gym:CartPole-v1", agent="dqn", preset="zoo")["env"]["observations"] == "raw"
    with pytest.raises(ValueError, match="observations must be one of"):
        resolve_config(env="gym:CartPole-v1", agent="dqn", observations="scaled")


def test_zoo_presets_are_the_zoos_settings_in_our_names():
    """The "zoo" DQN presets against rl-baselines3-zoo's dqn.yml as written there (by hand here):
    epsilon over exploration_fraction of n_timesteps, SB3's gradient_steps -1 as train_freq."""
    zoo = {"CartPole-v1": dict(lr=2.3e-3, batch_size=64, buffer_size=100_000, learning_starts=1_000, gamma=0.99,
                               target_update_interval=10, train_freq=256, gradient_steps=128,
                               exploration_steps=8_000, eps_end=0.04, hidden=(256, 256)),
           "Acrobot-v1": dict(lr=6.3e-4, batch_size=128, buffer_size=50_000, learning_starts=0, gamma=0.99,
                              target_update_interval=250, train_freq=4, gradient_steps=4, exploration_steps=12_000,
                              eps_end=0.1, hidden=(256, 256)),
           "MountainCar-v0": dict(lr=4e-3, batch_size=128, buffer_size=10_000, learning_starts=1_000, gamma=0.98,
                                  target_update_interval=600, train_freq=16, gradient_steps=8,
                                  exploration_steps=24_000, eps_end=0.07, hidden=(256, 256))}
    for gym_id, expect in zoo.items():
        agent = resolve_config(env=f"gym:{gym_id}", agent="dqn", preset="zoo")["agent"]
        assert {k: agent[k] for k in expect} == {k: list(v) if k == "hidden" else v for k, v in expect.items()}, gym_id


@pytest.mark.filterwarnings("ignore:.*out of date")
def test_infinite_bounds_without_documented_ones_are_squashed():
    """CartPole-v0 has no BOUNDS entry: its finite dims (x +-4.8, theta +-0.4189) map affinely,
    the infinite velocities through (1 + tanh v) / 2."""
    env = make_env("gym:CartPole-v0", None, [0])
    raw = torch.tensor([[1.2, -0.5, 0.1, 2.0]])
    th = 12 * 2 * math.pi / 360 * 2  # gymnasium's theta bound
    expect = [(1.2 + 4.8) / 9.6, (1 + math.tanh(-0.5)) / 2, (0.1 + th) / (2 * th), (1 + math.tanh(2.0)) / 2]
    np.testing.assert_allclose(env.to_unit_box(raw)[0].numpy(), expect, rtol=1e-6)
    env.close()


def test_a_step_cap_truncates_and_gymnasiums_is_the_default():
    env = env_class("gym:MountainCar-v0")([0], max_steps=25)
    td = env.reset()
    for t in range(25):
        assert t == 0 or not out["next", "done"].item()
        td["action"] = torch.tensor([1])
        out, td = env.step_and_maybe_reset(td)
    assert out["next", "truncated"].item() and not out["next", "terminated"].item()
    assert make_env("gym:MountainCar-v0", None, [0]).max_steps == 200  # gymnasium's registered cap


def test_batch_composition_invariance_on_cartpole():
    """Seed 4 alone equals seed 4 among others, for the env and for DGPQ and DQN on it."""
    for agent, extra in (("dgpq", {}), ("dqn", dict(batch_size=8, learning_starts=16, train_freq=4, gradient_steps=2,
                                                    hidden=(16,), exploration_steps=100))):
        cfg = dict(env="gym:CartPole-v1", agent=agent, episodes=6, **extra)
        both = run_experiment(resolve_config(seeds=[2, 4, 9], **cfg), progress=False)
        alone = run_experiment(resolve_config(seeds=[4], **cfg), progress=False)
        pd.testing.assert_frame_equal(both[both.seed == 4].reset_index(drop=True).drop(columns=list(TIMING_COLUMNS)),
                                      alone.drop(columns=list(TIMING_COLUMNS)))
        assert not both[both.seed == 2]["steps"].reset_index(drop=True).equals(alone["steps"])


def test_tiny_dqn_and_dgpq_rollouts_on_cartpole():
    for agent in ("dqn", "dgpq"):
        extra = dict(batch_size=8, learning_starts=8, train_freq=4, gradient_steps=1, hidden=(16,)) \
            if agent == "dqn" else {}
        df = run_experiment(resolve_config(env="gym:CartPole-v1", agent=agent, seeds=[0, 1], episodes=100,
                                           env_steps=150, **extra), progress=False)
        per_seed = df.groupby("seed").steps
        assert (per_seed.sum() >= 150).all() and ((per_seed.sum() - df.groupby("seed").steps.last()) < 150).all()
        assert df.terminated.any() and (df["return"] == df.steps).all()  # +1 per step
        if agent == "dqn":
            assert df.updates.max() > 0


def test_state_round_trip_mid_episode():
    env = make_env("gym:Acrobot-v1", None, [0, 1])
    td = env.reset()
    for _ in range(7):
        td["action"] = torch.tensor([0, 2])
        _, td = env.step_and_maybe_reset(td)
    state = env.state_dict()
    fresh = make_env("gym:Acrobot-v1", None, [0, 1])
    fresh.reset()
    fresh.load_state_dict(state)
    for _ in range(5):
        a = torch.tensor([1, 0])
        x = env.step(td.set("action", a))["next", "observation"]
        y = fresh.step(td.clone().set("action", a))["next", "observation"]
        assert torch.equal(x, y)
        td = td.set("observation", x)


@pytest.mark.parametrize("name, message", [
    ("gym:Pendulum-v1", "gym:Pendulum-v1 has Box actions; the suite's agents (DGPQ, DQN) need discrete ones"),
    ("gym:NoSuchEnv-v0", "unknown gymnasium id gym:NoSuchEnv-v0"),
    ("gym:", "unknown env 'gym:'"),
])
def test_unusable_ids_are_refused_in_one_line(name, message, capsys):
    with pytest.raises(ValueError, match=message.replace("(", r"\(").replace(")", r"\)")):
        env_class(name)
    argv = ["--env", name, "--episodes", "1", "--no-progress"]
    # in this process (a real one costs seconds of imports; test_run's full-disk test shows a real
    # train.py's error is one line, exit 2, no traceback)
    from trl_dgpq.commands.train import main
    with pytest.raises(SystemExit) as stop:
        main(argv)
    code, err = stop.value.code, capsys.readouterr().err
    assert code == 2 and "Traceback" not in err
    assert message.split(";")[0] in err.strip().splitlines()[-1]


def test_the_old_block_push_id_says_what_it_is_now(monkeypatch, capsys):
    """Before issue 17, importing the suite registered trl_dgpq/BlockPush-v0; now gymnasium's
    "module:id" form does, and the old name says so. (Here the adapter is already imported, so its
    registration is taken away; test_domains' fresh process shows importing the suite makes none.)"""
    from trl_dgpq.commands.train import main
    from trl_dgpq.envs.gym.env import PUSH_GYM_ID, describe
    assert PUSH_GYM_ID == GYM_ID
    monkeypatch.delitem(gymnasium.registry, "trl_dgpq/BlockPush-v0", raising=False)
    describe.cache_clear()
    try:
        with pytest.raises(SystemExit) as stop:
            main(["--env", "gym:trl_dgpq/BlockPush-v0", "--no-progress"])
    finally:
        describe.cache_clear()
    assert stop.value.code == 2
    assert f"the block-push id is now gym:{GYM_ID}" in capsys.readouterr().err.strip().splitlines()[-1]


@pytest.mark.filterwarnings("ignore:.*out of date")
def test_any_discrete_id_runs_with_defaults():
    cfg = resolve_config(env="gym:CartPole-v0", agent="random", seeds=[0], episodes=2)
    assert cfg["run"]["preset"] == "default"
    assert len(run_experiment(cfg, progress=False)) == 2


def test_budget_ends_a_seed_with_the_episode_that_reaches_it():
    """30-step episodes (a random walk does not reach the square's goal, 17 moves away, in 30): a budget
    of 60 is met exactly by the 2nd episode, 61 needs a 3rd."""
    for budget, episodes in ((60, 2), (61, 3)):
        df = run_experiment(resolve_config(agent="random", seeds=[0, 1], episodes=10, max_steps=30,
                                           env_steps=budget), progress=False)
        assert (df.steps == 30).all() and (df.groupby("seed").size() == episodes).all()


def test_an_envs_own_cap_ends_the_episode_and_odd_envs_do_not_resume():
    """The block-push id caps its episodes at 50 itself: with max_steps 60 our episode ends there
    (truncated), and the next step starts a new one. Its state is pybullet's, not Python's: it runs
    and saves, but a checkpoint is refused on loading, in one line."""
    env = env_class(f"gym:{GYM_ID}")([0], max_steps=60)
    td = env.reset()
    for t in range(51):
        td["action"] = torch.tensor([1])  # south, away from the goal: no success, no fall
        out, td = env.step_and_maybe_reset(td)
        if t == 49:
            assert out["next", "truncated"].item() and not out["next", "terminated"].item()
    assert not out["next", "done"].item() and env.t.item() == 1
    with pytest.raises(ValueError, match="cannot continue from a checkpoint"):
        env.load_state_dict(env.state_dict())
    env.close()


# ---------------------------------------------------------------- the reproduction's gym section (issue 29)
def test_the_reproduction_runs_each_learner_at_the_comparisons_budget_and_dqn_at_the_zoos():
    from trl_dgpq.commands.reproduce import experiments
    plan = experiments("report", ["gym"])
    run = {name: (c["run"]["env"], c["run"]["agent"], c["run"]["preset"], len(c["run"]["seeds"]), c["run"]["env_steps"])
           for name, c in plan.items()}
    assert run["cartpole-dgpq"] == ("gym:CartPole-v1", "dgpq", "default", 10, 20_000)
    assert run["mountaincar-dgpq"] == ("gym:MountainCar-v0", "dgpq", "default", 10, 30_000)
    assert run["acrobot-dqn"] == ("gym:Acrobot-v1", "dqn", "default", 10, 20_000)
    assert run["cartpole-dqn-tuned"] == ("gym:CartPole-v1", "dqn", "tuned", 10, 20_000)   # a study wrote it
    # the zoo's own budgets, epsilon over its exploration fraction of them (0.16 x 50,000; 0.12 x 100,000)
    assert run["cartpole-dqn-zoo"][2:] == ("zoo", 10, 50_000) and run["acrobot-dqn-zoo"][4] == 100_000
    assert plan["cartpole-dqn-zoo"]["agent"]["exploration_steps"] == 8_000
    assert plan["acrobot-dqn-zoo"]["agent"]["exploration_steps"] == 12_000
    assert plan["cartpole-dgpq"]["env"]["observations"] == "unit" and plan["cartpole-dqn"]["env"]["observations"] == "raw"
    assert set(experiments("smoke", ["gym"])) == {n for n in plan if n.startswith("cartpole-")}
    from trl_dgpq.envs.gym.analysis import reproductions
    sizes = {name: own for name, _, own in reproductions()}
    assert sizes["cartpole-dqn-zoo"] == {"smoke": (1, 100_000, 300), "quick": (2, 100_000, 1_100),
                                         "full": (10, 100_000, 50_000), "report": (10, 100_000, 50_000)}
    assert sizes["mountaincar-dgpq"] == {"quick": (2, 100_000, 1_100), "full": (10, 100_000, 30_000),
                                         "report": (10, 100_000, 30_000)}   # no smoke: one task is enough
    assert sizes["cartpole-dgpq"]["smoke"] == (1, 100_000, 300)
    assert all(isinstance(steps, int) for own in sizes.values() for _, _, steps in own.values())
    settings = {name: s for name, s, _ in reproductions()}
    assert settings["cartpole-dqn-zoo"] == dict(env="gym:CartPole-v1", agent="dqn", preset="zoo")
    assert settings["acrobot-dgpq-tuned"] == dict(env="gym:Acrobot-v1", agent="dgpq", preset="tuned")
    assert [n for n in sizes if n.startswith("cartpole-")] == ["cartpole-dgpq", "cartpole-dgpq-tuned", "cartpole-dqn",
                                                               "cartpole-dqn-tuned", "cartpole-dqn-zoo"]


def _run(agent: str, met_at, episodes: int = 30, steps: int = 10, preset: str = "tuned", budget: int = 300):
    """A CartPole run whose seed k returns 200 from its episode met_at[k] on (None: 20 always)."""
    from trl_dgpq.analysis.runs import Run
    rows = [dict(seed=k, episode=e, steps=steps, env_steps=e * steps,
                 **{"return": 200.0 if m is not None and e >= m else 20.0})
            for k, m in enumerate(met_at) for e in range(1, episodes + 1)]
    config = {"run": {"env": "gym:CartPole-v1", "agent": agent, "preset": preset, "env_steps": budget}}
    return Run(None, pd.DataFrame(rows), config)


def test_the_zoo_preset_is_the_zoos_settings_in_dqns_names_by_hand():
    """zoo_dqn at test time (the presets table calls it at import): the zoo's CartPole and MountainCar
    settings as DQNConfig overrides, epsilon over exploration_fraction of the zoo's own budget
    (0.16 x 50,000; 0.2 x 120,000); Acrobot's equal DQNConfig's defaults (SB3's gradient_steps -1 is
    train_freq, 4), so its preset overrides nothing but the raw observations."""
    from trl_dgpq.envs.gym.presets import RAW, zoo_dqn
    assert zoo_dqn("CartPole-v1") == {"env": RAW, "agent": dict(
        lr=2.3e-3, batch_size=64, buffer_size=100_000, learning_starts=1_000, target_update_interval=10,
        train_freq=256, gradient_steps=128, exploration_steps=8_000, eps_end=0.04)}
    assert zoo_dqn("MountainCar-v0") == {"env": RAW, "agent": dict(
        lr=4e-3, buffer_size=10_000, learning_starts=1_000, gamma=0.98, target_update_interval=600,
        train_freq=16, gradient_steps=8, exploration_steps=24_000, eps_end=0.07)}
    assert zoo_dqn("Acrobot-v1") == {"env": RAW, "agent": {}} and RAW == {"observations": "raw"}
