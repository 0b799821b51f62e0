"""The square's step (envs/square/env.py) by hand: the move and its jitter from each seed's own
stream, the walls, the goal's edge, each reward, and the reward noise from its own stream."""
import torch

from trl_dgpq.envs.square.env import SquareEnv

NORTH, SOUTH, EAST, WEST = 0, 1, 2, 3


def step(env, *actions):
    td = env.reset() if not hasattr(env, "_td_now") else env._td_now
    td = env.step(td.set("action", torch.tensor(actions)))
    env._td_now = td["next"].clone()
    return td["next"]


def draws(seeds, stream, n, **cfg):
    """The first ``n`` draws of a fresh env's ``stream`` ("rng" or "reward_rng"), one call a step."""
    other = SquareEnv(seeds=seeds, **cfg)
    return [getattr(other, stream).uniform(1)[:, 0] if stream == "rng" else getattr(other, stream).normal(1)[:, 0]
            for _ in range(n)]


def test_its_tensors_are_float64():
    env = SquareEnv(seeds=(0, 1), goal=(0.3, 0.7))
    assert env.goal.dtype == env.moves.dtype == env.pos.dtype == torch.float64
    assert env.goal.tolist() == [0.3, 0.7] and env.pos.shape == (2, 2)
    assert env.observation_spec["observation"].space.low.tolist() == [[0.0, 0.0]] * 2
    assert env.observation_spec["observation"].space.high.tolist() == [[1.0, 1.0]] * 2


def test_a_move_is_its_step_plus_the_seeds_own_jitter_on_the_moved_axis():
    seeds, noise = (3, 8), 0.05
    env = SquareEnv(seeds=seeds, noise=noise, goal=(0.3, 0.7))
    u1, u2 = draws(seeds, "rng", 2, noise=noise)
    first = step(env, EAST, NORTH)
    jitter = (2.0 * u1 - 1.0) * noise
    assert first["observation"].tolist() == [[0.1 + jitter[0].item(), 0.0], [0.0, 0.1 + jitter[1].item()]]
    second = step(env, NORTH, EAST)
    jitter2 = (2.0 * u2 - 1.0) * noise
    assert second["observation"].tolist() == [[0.1 + jitter[0].item(), 0.1 + jitter2[0].item()],
                                              [0.1 + jitter2[1].item(), 0.1 + jitter[1].item()]]
    goal = torch.tensor([0.3, 0.7], dtype=torch.float64)
    assert second["reward"][:, 0].tolist() == (2.0 - torch.linalg.vector_norm(goal - second["observation"],
                                                                               dim=1)).tolist()


def test_the_walls_hold_a_move_inside_the_square():
    env = SquareEnv(seeds=(0, 1), noise=0.0, step_size=0.25)
    env.reset()
    env.pos[:] = torch.tensor([[0.9, 0.1], [0.1, 0.95]], dtype=torch.float64)
    env._td_now = env._td(observation=env.pos.clone())
    assert step(env, EAST, NORTH)["observation"].tolist() == [[1.0, 0.1], [0.1, 1.0]]
    assert step(env, SOUTH, WEST)["observation"].tolist() == [[1.0, 0.0], [0.0, 1.0]]


def test_an_episode_ends_at_the_goals_radius_and_the_paper_reward_is_minus_one_before():
    env = SquareEnv(seeds=(0, 1), noise=0.0, step_size=0.25, goal_radius=0.25, reward="paper")
    env.reset()
    env.pos[:] = torch.tensor([[0.5, 1.0], [0.25, 1.0]], dtype=torch.float64)    # after east: 0.25 and 0.5 away
    env._td_now = env._td(observation=env.pos.clone())
    out = step(env, EAST, EAST)
    assert out["terminated"][:, 0].tolist() == [True, False]
    assert out["reward"][:, 0].tolist() == [0.0, -1.0] and out["reward"].dtype == torch.float64


def test_reward_noise_comes_from_its_own_stream_each_step():
    seeds = (4, 9)
    env = SquareEnv(seeds=seeds, noise=0.0, reward_noise=0.5, reward="paper")
    z1, z2 = draws(seeds, "reward_rng", 2, noise=0.0)
    assert step(env, NORTH, NORTH)["reward"][:, 0].tolist() == (-1.0 + 0.5 * z1).tolist()
    assert step(env, NORTH, NORTH)["reward"][:, 0].tolist() == (-1.0 + 0.5 * z2).tolist()


def test_every_tensor_and_spec_is_made_on_the_envs_device():
    """Made with torch's default device set to ``meta``: a tensor made without ``device=`` lands there."""
    with torch.device("meta"):
        env = SquareEnv(seeds=(0, 1), device="cpu")
    assert {t.device.type for t in (env.goal, env.moves, env.pos)} == {"cpu"}
    assert {spec.device.type for spec in (env.observation_spec["observation"], env.action_spec,
                                          env.reward_spec)} == {"cpu"}
