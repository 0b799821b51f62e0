"""Tests that fail on the mutants an independent audit found alive (issue 21, item 8): each
checks a hand-derived value or a closed form, not the code under test."""
import math

import pytest
import torch

from trl_dgpq.dgpq import argmax_random_ties
from trl_dgpq.gp import GPConfig, make_gp, make_kernel


def test_a_relative_difference_of_1e9_is_not_a_tie():
    q = torch.tensor([[1.0, 1.0 + 1e-9, 1.0], [-5.0, -5.0 - 5e-9, -5.0 + 5e-9]], dtype=torch.float64)
    for u in torch.rand(20, 2, 3):
        assert argmax_random_ties(q, u).tolist() == [1, 2]


def test_the_sparse_gps_novelty_tolerance_reaches_the_gp():
    cfg = GPConfig(backend="sparse", novelty_tol=0.5)
    gp = make_gp(cfg, 2, (1, 1), make_kernel(cfg, 2, [0], 1))
    assert gp.novelty_tol == 0.5


def test_gymnasium_ends_an_episode_at_our_step_cap_not_its_own():
    from trl_dgpq.envs.gym.env import gym_env
    env = gym_env("MountainCar-v0")([0], max_steps=300)   # gymnasium registers 200
    td, steps = env.reset(), 0
    while True:
        td["action"] = torch.tensor([1])                   # no push: never reaches the flag
        td = env.step(td)["next"]
        steps += 1
        if bool(td["done"][0]):
            break
        td = td.exclude("reward", "done", "terminated", "truncated")
    assert steps == 300 and bool(td["truncated"][0]) and not bool(td["terminated"][0])


def test_at_zero_risk_aversion_the_optimum_is_twap_and_its_costs_are_summed_by_hand():
    """AC00: E = eps X + gamma X^2 / 2 + (eta~ / tau) sum n_k^2, V = sigma^2 tau sum x_k^2, with
    n_k = X / N and x_k = X (1 - k / N) when lambda = 0."""
    from trl_dgpq.envs.liquidation.almgren_chriss import ACModel
    from trl_dgpq.envs.liquidation.env import LiquidationConfig
    m = ACModel.from_config(LiquidationConfig(lam=0.0))
    X, N, tau = m.shares, m.trades, m.tau
    eta_tilde = m.eta - m.gamma * tau / 2
    expect_e = m.eps * X + m.gamma * X * X / 2 + eta_tilde / tau * N * (X / N) ** 2
    expect_v = m.sigma2 * tau * sum((X * (1 - k / N)) ** 2 for k in range(1, N + 1))
    assert m.expected_shortfall() == pytest.approx(expect_e, rel=1e-12)
    assert m.variance() == pytest.approx(expect_v, rel=1e-12)
    torch.testing.assert_close(m.holdings(), X * (1 - torch.arange(N + 1, dtype=torch.float64) / N))


def test_the_ac_schedules_shortfall_spreads_as_the_closed_form_says():
    """400 seeds of the AC schedule, one episode each: the shortfall's s.d. is sqrt(V*) (the
    s.d. of an s.d. from 400 draws is ~3.5 %; 12 % is over three of them)."""
    from trl_dgpq.collectors.experiment import build, resolve_config
    from trl_dgpq.envs.liquidation.almgren_chriss import ACModel
    from trl_dgpq.envs.liquidation.env import LiquidationConfig
    config = resolve_config(env="liquidation", agent="ac-optimal", seeds=list(range(400)), episodes=1)
    env, agent = build(config)
    td, done = env.reset(), torch.zeros(400, dtype=torch.bool)
    while not done.all():
        td["action"] = agent.act(td)
        td = env.step(td)["next"]
        done |= td["done"].reshape(-1)
        shortfall = td["implementation_shortfall"].reshape(-1).clone() if done.all() else None
        td = td.exclude("reward", "done", "terminated", "truncated")
    sd = math.sqrt(ACModel.from_config(LiquidationConfig()).variance())
    assert float(shortfall.std()) == pytest.approx(sd, rel=0.12)


def test_an_experiments_own_values_win_over_the_defaults_and_defaults_set_applies(tmp_path):
    from trl_dgpq.collectors import sweep
    path = tmp_path / "s.toml"
    path.write_text('[defaults]\nseeds = 2\nepisodes = 3\n[defaults.set]\nnoise_var = 0.2\nlengthscale = 0.3\n'
                    '[[experiment]]\nname = "a"\nenv = "square"\nepisodes = 5\n[experiment.set]\nlengthscale = 0.4\n'
                    '[[experiment]]\nname = "b"\nenv = "square"\n')
    a, b = (sweep.read_sweep_file(path)[n] for n in ("a", "b"))
    assert a["run"]["episodes"] == 5 and b["run"]["episodes"] == 3 and a["run"]["seeds"] == [0, 1]
    assert a["agent"]["gp"]["noise_var"] == b["agent"]["gp"]["noise_var"] == 0.2
    assert a["agent"]["gp"]["lengthscale"] == 0.4 and b["agent"]["gp"]["lengthscale"] == 0.3


def test_the_level_noise_is_an_ou_recursion_from_zero_at_each_episode():
    """x_k = (1 - theta) x_{k-1} + sigma xi_k with x_0 = 0 at every episode's start, xi the
    seed's own N(0, 1) draws (replayed from an independent stream with the same key)."""
    from trl_dgpq.envs.liquidation.env import LiquidationEnv
    from trl_dgpq.rng import ENV_STREAM, SeedStreams
    sigma, theta, trades = 0.3, 0.15, 6
    env = LiquidationEnv([5], action_levels=11, level_noise=sigma, level_noise_theta=theta, trades=trades,
                         horizon=trades)
    xi = SeedStreams([5], ENV_STREAM)
    td = env.reset()
    for episode in range(2):
        x = 0.0
        for k in range(trades):
            td["action"] = torch.tensor([0])          # the level 0: only the noise sells
            td = env.step(td)
            x = (1 - theta) * x + sigma * float(xi.normal()[0])
            assert float(env.ou[0]) == pytest.approx(x, abs=1e-12), (episode, k)
            done = bool(td["next", "done"][0])
            td = env.reset() if done else td["next"]
            if done:
                break
        assert done
