"""evaluate: a run's checkpoint, exploration and learning off, on episodes training never met."""
import hashlib

import numpy as np

import pandas as pd
import pytest
import torch
from tensordict import TensorDict

from trl_dgpq.agents.ddpg import DDPG, DDPGConfig
from trl_dgpq.agents.dqn import DQN, DQNConfig
from trl_dgpq.collectors.evaluate import evaluate
from trl_dgpq.collectors.runner import RunError
from trl_dgpq.commands import evaluate as evaluate_command
from trl_dgpq.commands import train
from trl_dgpq.envs.f16.env import F16Env
from trl_dgpq.envs.gym.env import gym_env


def trained(tmp_path, *argv):
    out = tmp_path / "run"
    assert train.main([*map(str, argv), "--out", str(out), "--no-progress"]) == 0
    return out


def test_a_dgpq_run_is_evaluated_without_learning_and_its_checkpoint_is_unchanged(tmp_path):
    out = trained(tmp_path, "--seeds", "0,3", "--episodes", 4)
    digest = hashlib.sha256((out / "checkpoint.pt").read_bytes()).hexdigest()
    df = evaluate(out, episodes=3)
    assert list(df.seed) == [0, 0, 0, 3, 3, 3] and list(df.episode) == [1, 2, 3] * 2
    pd.testing.assert_frame_equal(pd.read_csv(out / "eval.csv"), df, check_exact=False)
    assert hashlib.sha256((out / "checkpoint.pt").read_bytes()).hexdigest() == digest
    # nothing learned: every evaluation row has the Q̂ the training ended with
    last = pd.read_csv(out / "episodes.csv").groupby("seed").last()
    for col in ("qhat_size", "qhat_updates", "gp_adds"):
        assert (df.groupby("seed")[col].agg(["min", "max"]).T == last[col]).all().all(), col


def test_evaluation_episodes_are_new_and_a_seeds_own(tmp_path):
    def first_states(env, steps=30):
        td, out = env.reset(), []
        for _ in range(steps):
            td["action"] = torch.ones(env.num_seeds, dtype=torch.long)
            td = env.step(td)["next"]
            out.append(td["state"].clone())
        return torch.stack(out, 1)
    train_ = first_states(F16Env([3]))
    alone = first_states(F16Env([3]).for_evaluation())
    batch = first_states(F16Env([8, 3]).for_evaluation())
    assert torch.equal(alone[0], batch[1]) and not torch.equal(alone[0], train_[0])
    cart = [gym_env("CartPole-v1")([7]), gym_env("CartPole-v1")([2, 7]).for_evaluation()]
    a, b = cart[0].reset()["observation"], cart[1].reset()["observation"]
    again = gym_env("CartPole-v1")([7]).for_evaluation().reset()["observation"]
    assert torch.equal(again[0], b[1]) and not torch.equal(a[0], b[1])



def test_evaluation_plays_the_envs_evaluation_streams_not_trainings(tmp_path):
    """An F-16 run of a fixed action ("hold", 2 seeds x 2 episodes of 20 steps, none leaves the
    envelope): its evaluation returns are those of a fresh env keyed for evaluation, played by hand,
    and none is a training return (on training's streams they would all be equal)."""
    out = trained(tmp_path, "--env", "f16", "--agent", "constant", "--action", "hold", "--max-steps", 20,
                  "--seeds", "4,9", "--episodes", 2)
    df = evaluate(out, episodes=2)
    env = F16Env([4, 9], max_steps=20).for_evaluation()
    td, rewards = env.reset(), []
    for _ in range(40):
        td["action"] = torch.ones(2, dtype=torch.long)
        step, td = env.step_and_maybe_reset(td)
        rewards.append(step["next", "reward"][:, 0])
    by_hand = torch.stack(rewards, 1).reshape(2, 2, 20).sum(-1)   # (seed, episode)
    assert df["return"].tolist() == pytest.approx(by_hand.flatten().tolist(), rel=1e-12)
    training = pd.read_csv(out / "episodes.csv")
    assert (training["steps"] == 20).all() and not np.isclose(df["return"], training["return"]).any()


@pytest.mark.parametrize("env_class", ["square", "liquidation"])
def test_each_stream_has_its_own_evaluation_key(env_class):
    """The square (env noise, reward noise) and liquidation (env noise, prices) keyed for evaluation:
    each stream draws its own numbers, none of them its training stream's nor another stream's."""
    from trl_dgpq.envs import domain
    Env = domain(env_class).env_class()
    training, evaluation = Env([5, 6]), Env([5, 6]).for_evaluation()
    names = ["rng", *(name for name, _ in Env._streams)]
    draws = [getattr(env, name).uniform(4) for env in (training, evaluation) for name in names]
    assert len(names) == 2 and all(not torch.equal(a, b) for i, a in enumerate(draws) for b in draws[i + 1:])

def test_dqn_exploits_with_epsilon_zero_and_draws_no_exploration_number():
    agent = DQN(DQNConfig(eps_init=1.0, eps_end=1.0, hidden=(8,)), [0, 1], 3, 4)  # epsilon 1: act is random
    obs = torch.rand(2, 3)
    td = TensorDict({"observation": obs}, [2])
    before = agent.explore_rng.counter
    expect = torch.stack([agent.qnet(obs.float())[i].argmax() for i in range(2)])
    assert torch.equal(agent.exploit(td), expect)
    assert agent.explore_rng.counter == before


def test_ddpg_exploits_without_noise():
    low, high = torch.zeros(2), torch.ones(2)
    from torchrl.data import Bounded
    agent = DDPG(DDPGConfig(ou_sigma=0.5), [0, 1], 3, Bounded(low, high, shape=(2,)))
    td = TensorDict({"observation": torch.rand(2, 3)}, [2])
    with torch.no_grad():
        expect = agent.actor(td["observation"].float()).clamp(0, 1).double()
    noise = agent.noise.clone()
    assert torch.equal(agent.exploit(td), expect) and torch.equal(agent.noise, noise)
    assert not torch.equal(agent.act(td), expect)  # training's action carries the OU noise



@pytest.mark.parametrize("agent_class, argv", [
    (DQN, ["--env", "corridor", "--agent", "dqn", "--episodes", 2]),
    (DDPG, ["--env", "liquidation", "--agent", "ddpg", "--episodes", 1, "--trades", 6, "--horizon", 6])])
def test_evaluation_acts_by_exploit_never_by_the_exploring_act(tmp_path, monkeypatch, capsys, agent_class, argv):
    """A trained DQN (still in its random warm-up) and DDPG (OU noise) evaluated with their
    training ``act`` made to fail: evaluation never calls it (and shows no progress unless asked)."""
    from trl_dgpq.collectors.evaluate import evaluate_job
    out = trained(tmp_path, "--seeds", "0,1", *argv)

    def explore(self, td):
        raise AssertionError(f"{type(self).__name__}.act (exploration) called in evaluation")
    monkeypatch.setattr(agent_class, "act", explore)
    capsys.readouterr()
    df = evaluate_job(out, 2)
    assert list(df.seed) == [0, 0, 1, 1] and list(df.episode) == [1, 2, 1, 2]
    assert capsys.readouterr().err == ""


def test_a_folder_without_a_checkpoint_is_one_line(tmp_path, capsys):
    with pytest.raises(RunError, match="holds no run with a checkpoint"):
        evaluate(tmp_path)
    assert evaluate_command.main([str(tmp_path), "--no-progress"]) == 2
    assert "error:" in capsys.readouterr().err


def test_the_square_qhat_grid_is_the_lipschitz_envelope_by_hand():
    """Q̂ with two pairs for action 0 (L = 2, V_max = 3, L1): Q̂_0(x) = min(3, 1 + 2|x - s1|_1,
    0.5 + 2|x - s2|_1); the other actions hold no pair: V_max everywhere."""
    from trl_dgpq.dgpq import DGPQ, DGPQConfig
    from trl_dgpq.envs.square.analysis import qhat_grid
    agent = DGPQ(DGPQConfig(lipschitz=2.0, v_max=3.0), [0, 1], 2, 4)
    for s, mu in (((0.2, 0.2), 1.0), ((0.9, 0.5), 0.5)):
        agent.qhat.insert(torch.tensor([s, s], dtype=torch.float64), torch.tensor([0, 0]),
                          torch.tensor([mu, mu], dtype=torch.float64), torch.tensor([True, False]))
    xs, q = qhat_grid(agent, n=5)
    for i, y in enumerate(xs):
        for j, x in enumerate(xs):
            expect = min(3.0, 1.0 + 2 * (abs(x - 0.2) + abs(y - 0.2)), 0.5 + 2 * (abs(x - 0.9) + abs(y - 0.5)))
            assert q[i, j, 0] == pytest.approx(expect)
    assert (q[:, :, 1:] == 3.0).all()
    assert (qhat_grid(agent, n=5, row=1)[1] == 3.0).all()   # seed row 1 got no pair


def test_plot_draws_qhat_and_the_evaluation_of_an_evaluated_dgpq_run(tmp_path):
    from trl_dgpq.commands import plot
    out = trained(tmp_path, "--seeds", "2", "--episodes", 3)
    evaluate(out, episodes=2)
    assert plot.main([str(out), "--out", str(tmp_path / "fig")]) == 0
    for name in ("steps_per_episode.png", "time_per_step.png", "qhat.png", "eval_returns.png"):
        assert (tmp_path / "fig" / name).stat().st_size > 10_000, name


def test_liquidation_holdings_of_the_schedules_are_their_closed_forms(tmp_path):
    """holdings() on evaluation episodes: ac-optimal holds the AC optimum x_k (to a few shares),
    TWAP 1 - k / N; and holdings.png is drawn for a learner beside them."""

    from trl_dgpq.commands import plot
    from trl_dgpq.envs.liquidation.almgren_chriss import ACModel
    from trl_dgpq.envs.liquidation.analysis import holdings
    from trl_dgpq.envs.liquidation.env import LiquidationConfig
    common = ["--env", "liquidation", "--seeds", "2", "--episodes", "2", "--trades", "12", "--horizon", "12"]
    for agent in ("ac-optimal", "twap", "dgpq"):
        assert train.main([*common, "--agent", agent, "--out", str(tmp_path / agent), "--no-progress"]) == 0
    cfg = LiquidationConfig(trades=12, horizon=12)
    opt = holdings(tmp_path / "ac-optimal", episodes=3)
    assert opt.shape == (2 * 3, 13)
    np.testing.assert_allclose(opt, np.broadcast_to(ACModel.from_config(cfg).holdings(1.0).numpy(), opt.shape),
                               atol=3.0 / cfg.shares)  # each trade rounds to a whole share
    np.testing.assert_allclose(holdings(tmp_path / "twap", episodes=1), [1 - np.arange(13) / 12] * 2,
                               atol=3.0 / cfg.shares)  # each trade rounds to a whole share
    assert plot.main([str(tmp_path / "ac-optimal"), str(tmp_path / "dgpq"), "--out", str(tmp_path / "fig")]) == 0
    assert (tmp_path / "fig" / "holdings.png").stat().st_size > 10_000


def test_push_animation_shows_the_learner_above_the_oracle(tmp_path):
    from PIL import Image

    from trl_dgpq.envs.push.analysis import CAMERA, FRAME, animation, camera, pixel
    from trl_dgpq.envs.push.env import PushConfig
    (w, h), cfg = FRAME, PushConfig()
    view, projection = camera(w, h)
    assert pixel(CAMERA["target"], view, projection, w, h) == pytest.approx((w / 2, h / 2))  # the centre
    # the 5 cm block spans at least 15 pixels (it was a few at 240 x 180), and the push, block to goal, fits
    (x0, _), (x1, _), (gx, _) = (pixel((x, y, 0.625), view, projection, w, h) for x, y in (
        cfg.block_start, (cfg.block_start[0] + 0.05, cfg.block_start[1]), cfg.goal))
    assert abs(x1 - x0) >= 15 and 0 < min(x0, gx) and max(x0, gx) < w
    out = trained(tmp_path, "--env", "push", "--seeds", "1", "--episodes", "1", "--max-steps", "6")
    gif = Image.open(animation(out, tmp_path))
    assert gif.size == (w, 2 * h) and 2 <= gif.n_frames <= 7          # at most 6 steps, plus the start
    gif.seek(gif.n_frames - 1)
    rgb = np.asarray(gif.convert("RGB")).astype(int)
    top, bottom = rgb[:h], rgb[h:]
    assert top.std() > 10 and bottom.std() > 10                        # both rendered, not blank
    red = (rgb[..., 0] > 150) & (rgb[..., 1] < 60) & (rgb[..., 2] < 60)
    assert red[:h].sum() > 50 and red[h:].sum() > 50                   # the goal's ring kept its red


def test_ctrl_c_mid_evaluation_keeps_the_finished_episodes_apart_from_eval_csv(tmp_path, capsys, monkeypatch):
    """Seeds step in lock-step, so a Ctrl-C at batched step m has finished each seed's episodes whose
    running sum of steps is below m: those rows (as the whole evaluation gives them) go to
    eval.partial.csv, eval.csv is not written, the command names the file; a whole evaluation later
    removes it."""
    from trl_dgpq.collectors import evaluate as module
    run = trained(tmp_path, "--env", "corridor", "--agent", "random", "--seeds", "0,1", "--episodes", 2)
    whole = evaluate(run, episodes=4, out=tmp_path / "whole")
    ends = whole.groupby("seed")["steps"].cumsum()
    m = int(ends.sort_values().iloc[2]) + 1          # past three episodes' ends, before the fourth's
    calls, act = [], module.Frozen.act

    def stopped(self, td):
        calls.append(1)
        if len(calls) == m:
            raise KeyboardInterrupt
        return act(self, td)
    monkeypatch.setattr(module.Frozen, "act", stopped)
    capsys.readouterr()
    assert evaluate_command.main([str(run), "--episodes", "4", "--no-progress"]) == 130
    partial = pd.read_csv(run / "eval.partial.csv")
    timing = ["wall_s", "cpu_s", "us_per_step"]
    pd.testing.assert_frame_equal(partial.drop(columns=timing), whole[ends < m].reset_index(drop=True)
                                  .drop(columns=timing), check_exact=False)
    assert len(partial) == 3 and not (run / "eval.csv").exists()
    assert capsys.readouterr().err.endswith(f"; the 3 episodes it finished are in {run / 'eval.partial.csv'}\n")
    monkeypatch.setattr(module.Frozen, "act", act)
    evaluate(run, episodes=4)
    assert (run / "eval.csv").exists() and not (run / "eval.partial.csv").exists()


def test_ctrl_c_before_any_evaluation_episode_ends_keeps_no_file(tmp_path, monkeypatch):
    """Interrupted at the first step: nothing finished, so no eval.partial.csv, and the error says so;
    a nested --out that does not exist yet is made whole (its parents too)."""
    from trl_dgpq.collectors import evaluate as module
    run = trained(tmp_path, "--env", "corridor", "--agent", "random", "--seeds", "0,1", "--episodes", 2)

    def at_once(self, td):
        raise KeyboardInterrupt
    with monkeypatch.context() as patched:
        patched.setattr(module.Frozen, "act", at_once)
        with pytest.raises(module.EvaluationInterrupted) as stop:
            evaluate(run, episodes=2)
    assert stop.value.path is None and stop.value.episodes == 0 and str(stop.value) == "no evaluation episode finished"
    assert not (run / "eval.partial.csv").exists() and not (run / "eval.csv").exists()
    kept = module.EvaluationInterrupted(tmp_path / "p.csv", 3)
    assert str(kept) == f"3 evaluation episodes kept in {tmp_path / 'p.csv'}" and kept.episodes == 3
    nested = tmp_path / "a" / "b" / "c"
    df = evaluate(run, episodes=2, out=nested)
    assert len(pd.read_csv(nested / "eval.csv")) == len(df) == 4
