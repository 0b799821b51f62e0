"""The pybullet block-pushing env, its scripted oracle and its gymnasium adapter."""
import io
import math
import warnings

import gymnasium as gym
import numpy as np
import pandas as pd
import pybullet as pb
import pytest
import torch
from tensordict import TensorDict
from torchrl.envs.utils import check_env_specs

from trl_dgpq.collectors.experiment import build, resolve_config
from trl_dgpq.collectors.online import OnlineCollector
from trl_dgpq.envs.push.env import PushEnv
from trl_dgpq.envs.push.gym_adapter import GYM_ID

N, S, E, W = range(4)


def step(env, actions):
    """Step with one action per seed; the "next" TensorDict."""
    return env.step(TensorDict({"action": torch.tensor(actions)}, batch_size=env.batch_size)).get("next")


def trajectory(env, actions):
    """Observations after each of ``actions`` (a list of per-seed action lists), (T, S, 6)."""
    return torch.stack([step(env, a).get("observation") for a in actions])


def test_specs_and_a_five_step_rollout():
    env = PushEnv([0, 1])
    check_env_specs(env)
    td = env.rollout(5, break_when_any_done=False)
    assert td.batch_size == (2, 5)
    assert td["next", "observation"].shape == (2, 5, 6) and td["next", "observation"].dtype == torch.float64
    assert td["next", "reward"].shape == (2, 5, 1)
    # the pusher is held at one height and the block rests on the table (z = 0.625 + 0.025)
    obs = td["next", "observation"]
    assert torch.allclose(obs[..., 2], obs[0, 0, 2]) and torch.allclose(obs[..., 5], torch.tensor(0.65, dtype=torch.float64), atol=2e-3)
    env.close()


def test_reward_is_two_minus_distance_and_the_goal_ends_the_episode():
    """Block 0.15 m from the goal, pusher just behind it: pushes east earn 2 - |block - goal|
    (computed here from the observation) until the block is within goal_radius, then 2 and
    terminated with success."""
    env = PushEnv([0], block_start=(0.35, 0.0), pusher_start=(0.25, 0.0), goal=(0.55, 0.0), noise=0.0)
    env.reset()
    for _ in range(5):
        nxt = step(env, [E])
        block = nxt["observation"][0, 3:]
        dist = math.dist(block.tolist(), [0.55, 0.0, 0.65])
        if bool(nxt["terminated"]):
            break
        assert float(nxt["reward"]) == pytest.approx(2.0 - dist, abs=1e-12)
        assert float(nxt["distance"]) == pytest.approx(dist, abs=1e-12)
        assert not nxt["success"].item() and math.dist(block[:2].tolist(), [0.55, 0.0]) > 0.1
    assert nxt["terminated"].item() and nxt["success"].item() and not nxt["fell_off"].item()
    assert float(nxt["reward"]) == 2.0 and math.dist(block[:2].tolist(), [0.55, 0.0]) <= 0.1
    env.close()


def test_pushing_the_block_off_the_table_is_terminal_but_no_success():
    env = PushEnv([0], block_start=(0.65, 0.0), pusher_start=(0.55, 0.0), goal=(0.0, 0.0), noise=0.0)
    env.reset()
    for k in range(4):
        nxt = step(env, [E])
        if bool(nxt["terminated"]):
            break
    assert nxt["fell_off"].item() and not nxt["success"].item() and k >= 1
    assert nxt["observation"][0, 3] > 0.75 or nxt["observation"][0, 5] < 0.625  # off the 1.5 m top
    env.close()


def test_a_block_off_the_table_is_no_success_even_within_the_goal_radius():
    """Goal at the east edge: a block placed just past the edge, 0.06 m from the goal, falls;
    the step is fell_off, not success."""
    env = PushEnv([0], goal=(0.70, 0.0), goal_radius=0.1, noise=0.0)
    env.reset()
    w = env.worlds[0]
    pb.resetBasePositionAndOrientation(w.block, [0.76, 0.0, 0.65], [0, 0, 0, 1], physicsClientId=w.client)
    nxt = step(env, [W])
    assert nxt["fell_off"].item() and not nxt["success"].item() and nxt["terminated"].item()
    assert float(nxt["reward"]) < 2.0
    env.close()


def test_moves_are_step_size_on_one_axis_with_noise_and_clipped_to_the_workspace():
    """Noise 0: three moves north in free space put the pusher 0.3 m north (within 2 mm; it
    tracks its target and stops with it). Noise 0.05: the moved axis changes by 0.1 +- 0.05
    per move, the other not at all. Five moves west from x = -0.55 stop at the workspace's
    edge, x = -0.85."""
    env = PushEnv([0], noise=0.0)
    env.reset()
    for _ in range(3):
        step(env, [N])
    x, y = env.worlds[0].positions()[:2]
    assert abs(y - 0.3) < 2e-3 and abs(x + 0.55) < 1e-3
    noisy = PushEnv([0], noise=0.05)
    noisy.reset()
    ys = [0.0]
    for _ in range(4):
        step(noisy, [N])
        assert float(noisy.target[0, 0]) == -0.55
        ys.append(float(noisy.target[0, 1]))
    moves = np.diff(ys)
    assert ((moves >= 0.05) & (moves <= 0.15)).all() and moves.std() > 0.005
    for _ in range(5):
        step(env, [W])
    assert float(env.target[0, 0]) == pytest.approx(-0.85) and abs(env.worlds[0].positions()[0] + 0.85) < 2e-3
    env.close()
    noisy.close()


def test_the_step_cap_truncates():
    env = PushEnv([0], max_steps=3)
    env.reset()
    flags = [(bool(n["terminated"]), bool(n["truncated"])) for n in (step(env, [N]) for _ in range(3))]
    assert flags == [(False, False), (False, False), (False, True)]
    env.close()


ACTIONS = [[E, N], [E, E], [N, E], [E, W], [S, E], [E, E], [W, S], [E, E]]


def test_deterministic_and_a_reset_restores_everything():
    """Same seed, same actions: bit-identical (with action noise). An episode after a reset
    equals the first episode of a fresh env (noise off, so the stream's position does not
    matter): contacts and velocities of the last episode leave nothing behind."""
    one, two = PushEnv([4, 9]), PushEnv([4, 9])
    one.reset(), two.reset()
    assert torch.equal(trajectory(one, ACTIONS), trajectory(two, ACTIONS))
    fresh, used = PushEnv([4], noise=0.0), PushEnv([4], noise=0.0)
    fresh.reset(), used.reset()
    trajectory(used, [[E], [E], [E], [N], [E], [S]])         # leaves the block moving, in contact
    used.reset()
    assert torch.equal(trajectory(fresh, [[a[0]] for a in ACTIONS]), trajectory(used, [[a[0]] for a in ACTIONS]))


def test_a_seed_does_not_depend_on_its_batch():
    """Seed 9 in [4, 9] and alone, the same actions: the same trajectory (its own noise and client)."""
    pair, alone = PushEnv([4, 9]), PushEnv([9])
    pair.reset(), alone.reset()
    assert torch.equal(trajectory(pair, ACTIONS)[:, 1], trajectory(alone, [[a[1]] for a in ACTIONS])[:, 0])
    # and the noise is the seed's: seed 4 moved the same way differs
    pair.reset(), alone.reset()
    assert not torch.equal(trajectory(pair, [[E, E]] * 3)[:, 0], trajectory(alone, [[E]] * 3)[:, 0])


def test_state_dict_round_trip_is_exact():
    """Save mid-episode (block moving, in contact) through torch.save, load into a fresh env:
    the next steps are bit-identical to the original's."""
    env = PushEnv([1, 2])
    env.reset()
    trajectory(env, ACTIONS[:3])
    buf = io.BytesIO()
    torch.save(env.state_dict(), buf)
    buf.seek(0)
    other = PushEnv([1, 2])
    other.reset()
    trajectory(other, [[W, S]] * 2)                           # a different history, then load
    other.load_state_dict(torch.load(buf, weights_only=True))
    assert torch.equal(other.t, env.t)
    assert torch.equal(trajectory(env, ACTIONS[3:]), trajectory(other, ACTIONS[3:]))


def test_close_disconnects_every_client_and_resets_add_no_bodies():
    env = PushEnv([0, 1, 2])
    clients = [w.client for w in env.worlds]
    bodies = env.num_bodies()
    assert bodies == [4, 4, 4]                                # plane, table, block, pusher
    for _ in range(1000):
        env.reset()
    assert env.num_bodies() == bodies
    assert all(pb.isConnected(c) for c in clients)
    env.close()
    assert not any(pb.isConnected(c) for c in clients)
    env.close()                                               # twice is harmless


def test_bad_settings_are_refused():
    for bad in (dict(block_start=(0.9, 0.0)), dict(goal=(0.0, 0.6)), dict(pusher_start=(-0.45, 0.02)),
                dict(noise=0.2), dict(substeps=0), dict(block_start=(0.5, 0.0))):
        with pytest.raises(ValueError):
            PushEnv([0], **bad)


def run_rows(seeds, episodes=1, **settings):
    config = resolve_config(seeds=seeds, episodes=episodes, env="push", **settings)
    env, agent = build(config)
    rows = OnlineCollector(env, agent, episodes, progress=False).run()
    env.close()
    return rows


def test_oracle_reaches_the_goal_in_at_least_95_percent_of_20_seeded_episodes():
    rows = run_rows(list(range(20)), agent="oracle")
    assert rows["success"].mean() >= 0.95 and not rows["fell_off"].any()
    assert rows["steps"].median() <= 12                       # 1 m at 0.1 m per push


def test_oracle_lines_up_from_the_side():
    """Block off the goal's line and the pusher on the far side: it must go round, push across,
    then along (not one straight push)."""
    rows = run_rows([0, 1, 2, 3], agent="oracle", block_start=(-0.3, 0.2), pusher_start=(0.0, -0.3),
                    noise=0.03, max_steps=80)
    assert rows["success"].all() and (rows["steps"] > 15).all()


def test_oracle_on_a_diagonal_and_its_limits():
    """Corner to opposite corner: x then y, no thrashing between axes. A goal smaller than a
    move, or moves wider than it can line up in, are refused (it would cycle forever)."""
    rows = run_rows([0, 1, 2, 3], agent="oracle", block_start=(-0.7, 0.45), goal=(0.55, -0.4), max_steps=100)
    assert rows["success"].all() and (rows["steps"] < 60).all()
    for bad in (dict(goal_radius=0.05), dict(step_size=0.2, goal_radius=0.2)):
        with pytest.raises(ValueError, match="oracle"):
            resolve_config(env="push", agent="oracle", **bad)


def test_random_agent_rarely_succeeds_and_rows_carry_success_and_fell_off():
    rows = run_rows([0, 1], episodes=2, agent="random", max_steps=20)
    assert {"success", "fell_off", "distance"} <= set(rows.columns)
    assert not rows["success"].any()                          # 1 m in 20 random moves: no
    assert ((rows["steps"] == 20) | rows["terminated"]).all()


def test_dgpq_presets_differ_only_in_the_kernel():
    rbf = resolve_config(env="push", agent="dgpq")["agent"]
    manifold = resolve_config(env="push", agent="dgpq", preset="manifold")["agent"]
    diff = {k for k in rbf if rbf[k] != manifold[k]} | {f"gp.{k}" for k in rbf["gp"] if rbf["gp"][k] != manifold["gp"][k]}
    assert diff == {"gp", "gp.kernel"}
    assert rbf["state_scale"] == pytest.approx([1 / 1.5, 1.0, 0.0, 1 / 1.5, 1.0, 0.0])


def test_gymnasium_adapter_is_the_same_env():
    """gym.make's env with reset(seed=3) steps exactly as seed 3 of PushEnv; the checker passes."""
    from gymnasium.utils.env_checker import check_env
    env = gym.make(GYM_ID, max_steps=12)
    with warnings.catch_warnings():
        warnings.simplefilter("error")      # e.g. "not equal although similar": a reset that is not exact
        check_env(env.unwrapped)
    obs, info = env.reset(seed=3)
    ours = PushEnv([3], max_steps=12)
    first = ours.reset()
    assert np.array_equal(obs, first["observation"][0].numpy())
    assert info == dict(success=False, fell_off=False, distance=float(first["distance"][0]))
    for a in [E, E, N, E, S, E]:
        obs, reward, terminated, truncated, info = env.step(a)
        nxt = step(ours, [a])
        assert np.array_equal(obs, nxt["observation"][0].numpy()) and reward == float(nxt["reward"])
        assert (terminated, truncated) == (bool(nxt["terminated"]), bool(nxt["truncated"]))
    for bad in (7, -1, True, 1.5):
        with pytest.raises(ValueError):
            env.step(bad)
    env.close()
    ours.close()


@pytest.mark.filterwarnings("ignore:.*render_mode")
def test_gymnasium_adapter_episode_boundaries_and_streams():
    """Stepping after the episode ended raises until reset(); an unseeded reset goes on with
    the stream (other noise), a seeded one starts it again."""
    env = gym.make(GYM_ID, max_steps=2).unwrapped
    with pytest.raises(RuntimeError):
        env.step(E)
    env.reset(seed=5)
    first = [env.step(E)[0] for _ in range(2)]
    with pytest.raises(RuntimeError):
        env.step(E)
    env.reset()
    assert not np.array_equal(env.step(E)[0], first[0])          # the stream went on
    env.reset(seed=5)
    assert np.array_equal(env.step(E)[0], first[0])
    with pytest.raises(ValueError, match="render"):
        gym.make(GYM_ID, render_mode="human")
    env.close()


def test_gymnasium_adapter_says_why_and_reads_its_env_s_step():
    """The refusals in words; seed 0 by default and PushEnv seeded with the seed given; every info
    field and a termination read from the step's TensorDict (a stub env's: a short episode seldom
    succeeds, falls off and ends at once)."""
    from trl_dgpq.envs.push.gym_adapter import GymPushEnv
    env = GymPushEnv(max_steps=2)
    with pytest.raises(RuntimeError, match=r"^call reset\(\) before step\(\), and again after an episode ends$"):
        env.step(E)
    obs, _ = env.reset()
    with pytest.raises(ValueError, match=r"^action must be an integer in \[0, 4\), got 7$"):
        env.step(7)
    for seed, adapter in ((0, GymPushEnv(max_steps=2)), (3, GymPushEnv(seed=3, max_steps=2))):
        ours = PushEnv([seed], max_steps=2)                         # the step's noise is the seed's
        ours.reset(), adapter.reset()
        assert np.array_equal(adapter.step(E)[0], step(ours, [E])["observation"][0].numpy())
        ours.close(), adapter.close()
    info = TensorDict({"success": torch.tensor([True]), "fell_off": torch.tensor([True]),
                       "distance": torch.tensor([0.25])}, batch_size=[1])
    assert GymPushEnv._info(info) == {"success": True, "fell_off": True, "distance": 0.25}

    class Ends:
        def step(self, td):
            return TensorDict({"next": TensorDict({
                "observation": torch.zeros(1, len(obs)), "reward": torch.tensor([[1.5]]),
                "terminated": torch.tensor([[True]]), "truncated": torch.tensor([[False]]),
                "success": torch.tensor([True]), "fell_off": torch.tensor([False]), "distance": torch.tensor([0.0])},
                batch_size=[1])}, batch_size=[1])
    real, env.env = env.env, Ends()
    _, reward, terminated, truncated, info = env.step(E)
    assert (reward, terminated, truncated, info["success"]) == (1.5, True, False, True)
    with pytest.raises(RuntimeError, match="again after an episode ends"):
        env.step(E)
    env.env = real
    env.close()


def test_a_failed_construction_leaves_no_client_connected(monkeypatch):
    from trl_dgpq.envs.push import env as push

    def connected():
        return sum(pb.isConnected(i) for i in range(512))
    before, built = connected(), []
    build = push._World._build

    def flaky(self, cfg):
        built.append(self.client)
        if len(built) == 2:
            raise RuntimeError("injected")
        build(self, cfg)
    monkeypatch.setattr(push._World, "_build", flaky)
    with pytest.raises(RuntimeError, match="injected"):
        PushEnv([0, 1, 2])
    assert len(built) == 2 and connected() == before


def test_plot_table_counts_successes_in_the_last_episodes(tmp_path):
    """push.md by hand: seed 0 succeeds in episodes 2-3 (10 and 12 steps), seed 1 never; over
    the last 2 episodes: 2 of 4 successes, 11 steps; first success: seed 0 at 2, seed 1
    never, so the median over seeds counts it as never."""
    from trl_dgpq.analysis import load_run
    from trl_dgpq.envs.push.analysis import table
    run = tmp_path / "r"
    run.mkdir()
    rows = [(0, 1, 50, False), (0, 2, 10, True), (0, 3, 12, True), (1, 1, 50, False), (1, 2, 50, False),
            (1, 3, 49, False)]
    pd.DataFrame([dict(seed=s, episode=e, steps=n, success=w, fell_off=False, wall_s=0.1 * n, distance=0.0)
                  for s, e, n, w in rows]).to_csv(run / "episodes.csv", index=False)
    (run / "config.json").write_text('{"run": {"env": "push", "agent": "oracle", "preset": "shaped"}, "env": {}, '
                                     '"agent": {}}')
    text = table([load_run(run)], ["r"], last=2)
    cells = [c.strip() for c in text.splitlines()[2].split("|")]
    assert cells[3:7] == ["50.0%", "11.0", "0.0%", "never (1 never)"]
    assert cells[8] == "100.00"                                # 0.1 s per step


def test_push_figure_has_a_title_and_whole_episodes(tmp_path, saved_figures):
    """push.png: titled (it had none without a --title), episodes ticked at whole numbers (a
    short run was ticked at 1.5, 2.5)."""
    from tests.test_report import fake_run
    from trl_dgpq.analysis import load_run
    from trl_dgpq.envs.push.analysis import figures
    folder = fake_run(tmp_path / "p", "push", {0: [50] * 4, 1: [40] * 4}, agent="oracle")
    df = pd.read_csv(folder / "episodes.csv")
    df.assign(distance=np.linspace(1.0, 0.1, 8), success=df.index % 3 == 0, fell_off=False).to_csv(
        folder / "episodes.csv", index=False)
    figures([load_run(folder)], ["oracle"], tmp_path)
    assert saved_figures.problems("push.png") == []


def test_a_run_disconnects_its_clients_when_it_ends_not_when_collected(tmp_path):
    """A study runs trial after trial in one process: each run's physics clients are released as
    it ends (the garbage collector, off here, may never free an env caught in a cycle)."""
    import gc

    from trl_dgpq.collectors import runner
    from trl_dgpq.collectors.experiment import run_experiment

    def connected():
        return sum(pb.isConnected(i) for i in range(512))
    before = connected()
    gc.disable()
    try:
        for k in range(2):
            config = resolve_config(env="push", agent="random", seeds=[0, 1, 2], episodes=1, max_steps=3)
            runner.start(config, runner.RunFolder.create(str(tmp_path / f"run{k}"), "x"), progress=False)
            assert connected() == before
            run_experiment(config, progress=False)
            assert connected() == before
    finally:
        gc.enable()
