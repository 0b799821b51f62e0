"""The Almgren-Chriss model (envs/liquidation/almgren_chriss.py) and the liquidation env's rules
(envs/liquidation/env.py) by hand on small markets where tau is not 1: the lambda -> 0 limit, the
schedule between the limit and the default's urgency, any schedule's cost, the level noise, the
log-returns, and the state a checkpoint keeps. (The price path's cost where tau is 2.5: test_liquidation's
path-cost test.)"""
import math
from types import SimpleNamespace

import pytest
import torch

from trl_dgpq.envs.liquidation.almgren_chriss import ACModel
from trl_dgpq.envs.liquidation.env import LiquidationConfig, LiquidationEnv
from trl_dgpq.rng import ENV_STREAM, SeedStreams

D = torch.float64
# a market of 3 trades over 6 days (tau = 2), prices in dollars, 6 shares
SMALL = dict(shares=6.0, start_price=50.0, horizon=6.0, trades=3, sigma2=0.5, eta=0.1, gamma=0.02, eps=0.05)


def market(lam):
    return ACModel(**SMALL, lam=lam)


# ------------------------------------------------------------------ the model
def test_the_market_of_a_config_by_hand():
    m = ACModel.from_config(LiquidationConfig(start_price=40.0, annual_volatility=0.2, trading_days=100.0,
                                              spread=0.1, daily_volume=1e5, horizon=10.0, trades=5, lam=2e-6,
                                              shares=3000))
    assert (m.shares, m.start_price, m.horizon, m.trades, m.lam) == (3000.0, 40.0, 10.0, 5, 2e-6)
    assert m.sigma2 == pytest.approx((0.2 / 10 * 40) ** 2, rel=1e-15)
    assert (m.eta, m.gamma, m.eps, m.tau) == pytest.approx((0.1 / 1e3, 0.1 / 1e4, 0.05, 2.0), rel=1e-15)
    assert m.eta_tilde == pytest.approx(1e-4 - 1e-5 * 2 / 2, rel=1e-15)


def test_without_risk_aversion_the_schedule_sells_evenly_and_the_closed_forms_are_the_sums():
    m = market(0.0)
    assert m.kappa == 0.0
    assert m.holdings().tolist() == [6.0, 4.0, 2.0, 0.0] and m.holdings(3.0).tolist() == [3.0, 2.0, 1.0, 0.0]
    assert m.trade_list(9.0).tolist() == pytest.approx([3.0, 3.0, 3.0], rel=1e-15) and m.trade_list().tolist() == [2.0, 2.0, 2.0]
    assert m.sell_fractions().tolist() == pytest.approx([1 / 3, 1 / 2, 1.0], rel=1e-15)
    eta_t = 0.1 - 0.02 * 2 / 2                                        # eta~ = eta - gamma tau / 2
    # E = eps x + gamma x^2 / 2 + (eta~ / tau) N (x / N)^2 = eps x + (gamma / 2 + eta~ / T) x^2
    assert m.expected_shortfall(3.0) == pytest.approx(0.05 * 3 + (0.01 + eta_t / 6) * 9, rel=1e-14)
    assert m.expected_shortfall() == pytest.approx(0.05 * 6 + (0.01 + eta_t / 6) * 36, rel=1e-14)
    # V = sigma^2 tau sum_k x_k^2 = 0.5 x 2 x ((2/3)^2 + (1/3)^2 + 0) x^2
    assert m.variance(3.0) == pytest.approx(0.5 * 2 * 5 / 9 * 9, rel=1e-14)
    assert m.variance() == pytest.approx(0.5 * 2 * 5 / 9 * 36, rel=1e-14)
    assert m.utility() == pytest.approx(m.expected_shortfall(), rel=1e-15)     # lambda 0


def test_a_mild_urgency_follows_the_sinh_schedule_not_the_even_one():
    """kappa T about 0.5: far from the limit's 1e-9, the sinh schedule sells sooner than evenly."""
    lam = 2 * 0.08 * (math.cosh(1 / 6) - 1) / (4 * 0.5)   # (2 / tau^2)(cosh k tau - 1) = lam s2 / eta~, eta~ 0.08
    m = market(lam)
    k = math.acosh(1 + lam * 0.5 * 4 / (2 * 0.08)) / 2
    assert m.kappa == pytest.approx(k, rel=1e-14) == pytest.approx(1 / 12, rel=1e-12)
    by_hand = [6 * math.sinh(k * (6 - t)) / math.sinh(k * 6) for t in (0, 2, 4, 6)]
    assert m.holdings().tolist() == pytest.approx(by_hand, rel=1e-14)
    assert m.holdings()[1] < 4.0                                               # sooner than evenly
    n = m.trade_list()
    assert m.expected_shortfall() == pytest.approx(m.cost(n)["expected_shortfall"], rel=1e-12)
    assert m.variance() == pytest.approx(m.cost(n)["variance"], rel=1e-12)
    assert m.sell_fractions().tolist() == pytest.approx([1 - by_hand[i + 1] / by_hand[i] for i in range(3)], rel=1e-12)


def test_an_impossible_market_is_refused_in_words():
    m = ACModel(**{**SMALL, "gamma": 0.2}, lam=1e-6)          # eta~ = 0.1 - 0.2 x 2 / 2 = -0.1
    with pytest.raises(ValueError) as err:
        m.kappa
    assert str(err.value) == ("eta~ = eta - gamma tau / 2 must be > 0, got -0.1: more trades or a larger "
                              "spread-to-volume ratio")
    with pytest.raises(ValueError, match="eta~"):
        LiquidationConfig(trades=1, horizon=60.0).cross_check()


def test_any_schedules_cost_by_the_sums():
    """Trades 2, 0, 4 (the zero trade pays no spread, the one share trade does) in the tau = 2 market;
    a buy (-1) pays the spread as a sale does (eps sign(n) n), as the env charges it."""
    m = market(0.3)
    for n, held in (([2.0, 0.0, 4.0], [4.0, 4.0, 0.0]), ([1.0, 5.0, 0.0], [5.0, 0.0, 0.0]),
                    ([7.0, -1.0, 0.0], [-1.0, 0.0, 0.0])):
        e = 0.05 * sum(abs(v) for v in n) + 0.5 * 0.02 * 36 + (0.08 / 2) * sum(v * v for v in n)
        v = 0.5 * 2 * sum(h * h for h in held)
        got = m.cost(torch.tensor(n, dtype=torch.float32))
        assert got == pytest.approx(dict(expected_shortfall=e, variance=v, utility=e + 0.3 * v), rel=1e-6)
        assert set(got) == {"expected_shortfall", "variance", "utility"}
    exact = m.cost([1.0, 5.0, 0.0])                    # float64
    assert exact["expected_shortfall"] == pytest.approx(0.05 * 6 + 0.5 * 0.02 * 36 + 0.04 * 26, rel=1e-15)
    # the env's own account of a schedule on a noise-free path (a buy included) is the same cost
    env = LiquidationEnv([0], trades=3, shares=6.0)
    for n in ([2.0, 0.0, 4.0], [7.0, -1.0, 0.0]):
        trades = torch.tensor(n, dtype=torch.float64)
        assert float(env.path_cost(trades, torch.zeros(1, 3, dtype=torch.float64))) == pytest.approx(
            env.model.cost(trades)["utility"], rel=1e-12)


# ------------------------------------------------------------------ the env
def test_two_levels_are_allowed_and_one_or_noise_without_levels_is_refused_in_words():
    assert LiquidationConfig(action_levels=2).cross_check() is None
    with pytest.raises(ValueError) as err:
        LiquidationConfig(action_levels=1).cross_check()
    assert str(err.value) == "action_levels must be 0 (continuous) or >= 2, got 1"
    with pytest.raises(ValueError) as err:
        LiquidationConfig(level_noise=0.1).cross_check()
    assert str(err.value) == "level_noise applies to discrete levels: set action_levels >= 2"


def test_the_envs_state_and_levels_are_float64_and_its_specs_what_an_agent_reads():
    env = LiquidationEnv([0, 1], action_levels=5, trades=4)
    assert env.levels.tolist() == [0.0, 0.25, 0.5, 0.75, 1.0] and env.levels.dtype == D
    assert {getattr(env, name).dtype for name in ("x", "price", "returns", "shortfall", "ac_cost", "ou", "xi",
                                                  "optimal_ac_cost", "noise_free_ac_cost")} == {D}
    assert env.episode.dtype == torch.long and env.episode.tolist() == [-1, -1]
    spec = env.observation_spec
    assert spec["trades_left"].space.low.tolist() == [0.0, 0.0] and spec["trades_left"].space.high.tolist() == [4.0] * 2
    assert spec["shares_left"].space.high.tolist() == [1e6, 1e6]
    box = LiquidationEnv([0]).action_spec
    assert box.space.low.tolist() == [[0.0]] and box.space.high.tolist() == [[1.0]] and box.dtype == D


def test_level_noise_is_an_ou_process_from_the_seeds_env_stream():
    """theta 0.3, sigma 0.2: ou_k = 0.7 ou_{k-1} + 0.2 z_k, z from the seed's env stream; the fraction
    sold is the level plus ou, within [0, 1]; price noise off, so shares are the only thing drawn."""
    seeds = (4, 9)
    env = LiquidationEnv(list(seeds), action_levels=5, level_noise=0.2, level_noise_theta=0.3, trades=5,
                         shares=1000, price_noise=False)
    mine = SeedStreams(seeds, ENV_STREAM)
    td, x, ou = env.reset(), torch.full((2,), 1000.0, dtype=D), torch.zeros(2, dtype=D)
    for action in ([2, 1], [1, 2], [3, 0]):
        ou = 0.7 * ou + 0.2 * mine.normal()
        fraction = (torch.tensor([0.25 * a for a in action], dtype=D) + ou).clamp(0.0, 1.0)
        sold = torch.round(fraction * x).clamp(min=0.0).minimum(x)
        td = env.step(td.set("action", torch.tensor(action)))
        x = x - sold
        assert td["next", "shares_left"].tolist() == x.tolist()
        assert env.ou.tolist() == pytest.approx(ou.tolist(), rel=1e-15)
        td = env.step_mdp(td)


def test_level_noise_past_the_box_sells_all_or_nothing():
    env = LiquidationEnv([0, 1], action_levels=3, level_noise=0.1, trades=5, shares=1000, price_noise=False)
    td = env.reset()
    env.ou[:] = torch.tensor([0.5, -0.5], dtype=D) / 0.85                  # after the step's decay: +-0.5 + 0.1 z
    env.rng = type("Zero", (), {"normal": staticmethod(lambda: torch.zeros(2, dtype=D))})()
    out = env.step(td.set("action", torch.tensor([2, 0])))["next"]         # 1 + 0.5, 0 - 0.5
    assert out["shares_left"].tolist() == [0.0, 1000.0]
    env = LiquidationEnv([0], action_levels=3, level_noise=0.1, trades=5, shares=1000, price_noise=False)
    td = env.reset()
    env.ou[:] = 0.1 / 0.85                                                 # 0.5 + 0.1: 60 %
    env.rng = type("Zero", (), {"normal": staticmethod(lambda: torch.zeros(1, dtype=D))})()
    assert env.step(td.set("action", torch.tensor([1])))["next", "shares_left"].tolist() == [400.0]


def test_the_log_returns_are_each_trades_price_move_newest_last():
    """Price noise off: each trade moves the price by its permanent impact alone, S_k = S_{k-1} - gamma n_k."""
    env = LiquidationEnv([0], trades=5, shares=10_000, price_noise=False, daily_volume=1e4)
    gamma = 0.125 / (0.1 * 1e4)
    td, price, moves = env.reset(), 50.0, []
    for fraction, x in ((0.5, 10_000), (0.5, 5_000)):
        n = round(fraction * x)
        moves.append(math.log((price - gamma * n) / price))
        price -= gamma * n
        td = env.step_mdp(env.step(td.set("action", torch.tensor([[fraction]], dtype=D))))
    assert td["observation"][0, :6].tolist() == pytest.approx([0.0] * 4 + moves, rel=1e-12)


def test_the_last_trades_return_moves_the_price_by_the_last_draw():
    env = LiquidationEnv([3], trades=2, horizon=2.0, shares=1000)
    td = env.reset()
    m, xi = env.model, env.xi[0].tolist()
    step = math.sqrt(m.sigma2 * m.tau)
    first = 50.0 + step * xi[0] - m.gamma * 500
    td = env.step_mdp(env.step(td.set("action", torch.tensor([[0.5]], dtype=D))))
    out = env.step(td.set("action", torch.tensor([[1.0]], dtype=D)))["next"]
    assert out["observation"][0, 4:6].tolist() == pytest.approx(
        [math.log(first / 50.0), math.log((first + step * xi[1] - m.gamma * 500) / first)], rel=1e-12)


def test_the_schedules_last_trade_sells_what_is_left():
    env = LiquidationEnv([0], trades=3, shares=1000)
    assert env._schedule_trades(torch.zeros(3, dtype=D)).tolist() == [0.0, 0.0, 1000.0]
    assert env._schedule_trades(torch.tensor([0.25, 0.5, 0.0], dtype=D)).tolist() == [250.0, 375.0, 375.0]
    odd = LiquidationEnv([0], trades=2, horizon=2.0, shares=2 ** 24 + 1)             # not a float32 number
    assert odd._schedule_trades(torch.zeros(2, dtype=D)).tolist() == [0.0, 2 ** 24 + 1]


def test_a_mid_episode_state_keeps_its_noise_free_cost():
    env = LiquidationEnv(seeds=[0, 1])
    td = env.reset()
    env.step(td.set("action", torch.full((2, 1), 0.1, dtype=D)))
    state = env.state_dict()
    fresh = LiquidationEnv(seeds=[0, 1])
    fresh.load_state_dict(state)
    assert torch.equal(fresh.noise_free_ac_cost, env.noise_free_ac_cost) and (env.noise_free_ac_cost > 0).all()
    assert torch.equal(fresh.optimal_ac_cost, env.optimal_ac_cost)


def test_every_spec_is_made_on_the_envs_device():
    """Made with torch's default device set to ``meta``: a spec made without ``device=`` lands there.
    (The env itself is not: ACModel's schedule is made on torch's default device.)"""
    with torch.device("meta"):
        continuous = LiquidationEnv.describe(device="cpu")
        levels = LiquidationEnv.describe(LiquidationConfig(action_levels=3), device="cpu")
    specs = [continuous.observation_spec, continuous.observation_spec["trades_left"], continuous.action_spec,
             levels.action_spec]
    assert {spec.device.type for spec in specs} == {"cpu"}


# ------------------------------------------------------------------ the scripted schedules
def test_twap_sells_one_nth_of_the_rest_and_a_schedule_reads_its_trade_from_the_trades_left():
    """TWAP over 4 trades sells 1/4, 1/3, 1/2 and all of what is left, exactly (float64); a
    schedule's trade k is trades - trades_left, held within 0..N-1 (a step past the last trade
    sells the rest, one before the first the first fraction)."""
    from tensordict import TensorDict

    from trl_dgpq.envs.liquidation.baselines import SchedulePolicy, TWAPPolicy
    fractions = TWAPPolicy.schedule(SimpleNamespace(trades=4))
    assert fractions.dtype == torch.float64 and fractions.tolist() == [1 / 4, 1 / 3, 1 / 2, 1.0]
    policy = SchedulePolicy(torch.tensor([0.4, 0.3, 0.2, 0.1], dtype=torch.float32), trades=4)
    td = TensorDict({"trades_left": torch.tensor([4.0, 3.0, 2.0, 1.0, 0.0, 5.0, -1.0])}, batch_size=[7])
    sold = policy.act(td)
    assert sold.shape == (7, 1) and sold.dtype == torch.float64
    assert sold[:, 0].tolist() == pytest.approx([0.4, 0.3, 0.2, 0.1, 0.1, 0.4, 0.1], abs=1e-7)
