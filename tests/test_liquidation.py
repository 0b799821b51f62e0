"""The Almgren-Chriss liquidation env and its closed-form optimum, against hand
calculations and the reference numbers of SPEC 3.2."""
import math

import pytest
import torch
from torchrl.envs.utils import check_env_specs

from trl_dgpq.envs.liquidation.almgren_chriss import ACModel
from trl_dgpq.collectors.experiment import build, resolve_config, run_experiment
from trl_dgpq.collectors.online import OnlineCollector
from trl_dgpq.envs.liquidation.env import LiquidationConfig, LiquidationEnv

D = torch.float64
# The defaults by hand: sigma^2 = (0.12 / sqrt(250) * 50)^2 = 36 / 250 per day, tau = 1 day,
# eta = 0.125 / (0.01 * 5e6), gamma = 0.125 / (0.1 * 5e6), eps = 0.125 / 2.
SIGMA2, ETA, GAMMA, EPS, LAM, X = 0.144, 2.5e-6, 2.5e-7, 0.0625, 1e-6, 1e6
U_STAR = 704_723.22


def test_model_matches_the_reference_numbers():
    m = ACModel.from_config(LiquidationConfig())
    assert (m.sigma2, m.eta, m.gamma, m.eps, m.tau) == pytest.approx((SIGMA2, ETA, GAMMA, EPS, 1.0))
    # kappa by bisection on (2 / tau^2)(cosh kappa - 1) = lambda sigma^2 / eta~, not the model's acosh
    target, lo, hi = LAM * SIGMA2 / (ETA - GAMMA / 2), 0.0, 5.0
    for _ in range(200):
        mid = (lo + hi) / 2
        lo, hi = (mid, hi) if 2 * (math.cosh(mid) - 1) < target else (lo, mid)
    assert m.kappa == pytest.approx(lo, rel=1e-12) and m.kappa == pytest.approx(0.24562, abs=1e-5)
    assert m.expected_shortfall() == pytest.approx(477_712.60, abs=0.01)
    assert math.sqrt(m.variance()) == pytest.approx(476_456, abs=1)
    assert m.utility() == pytest.approx(U_STAR, abs=0.01)
    assert m.trade_list()[0] == pytest.approx(217_778, abs=1)


def test_closed_forms_equal_the_sums_over_the_optimal_schedule():
    """E* and V* (closed forms) against E = eps X + gamma X^2 / 2 + (eta~ / tau) sum n^2 and
    V = sigma^2 tau sum x^2 summed over the schedule, for the defaults and another market."""
    for cfg in (LiquidationConfig(), LiquidationConfig(trades=12, horizon=30, lam=3e-6, shares=250_000)):
        m = ACModel.from_config(cfg)
        n = m.trade_list()
        x = m.holdings()[1:]
        e = EPS * n.sum() + 0.5 * m.gamma * n.sum() ** 2 + (m.eta - m.gamma * m.tau / 2) / m.tau * (n * n).sum()
        v = m.sigma2 * m.tau * (x * x).sum()
        assert float(n.sum()) == pytest.approx(cfg.shares)
        assert m.expected_shortfall() == pytest.approx(float(e), rel=1e-10)
        assert m.variance() == pytest.approx(float(v), rel=1e-10)


def test_the_optimum_beats_nearby_schedules():
    m = ACModel.from_config(LiquidationConfig())
    best = m.cost(m.trade_list())["utility"]
    g = torch.Generator().manual_seed(0)
    for _ in range(20):
        n = m.trade_list() * (1 + 0.05 * torch.randn(60, generator=g, dtype=D))
        n = n / n.sum() * X
        assert m.cost(n)["utility"] > best


def test_spec_check_both_action_kinds():
    check_env_specs(LiquidationEnv([0, 1]))
    check_env_specs(LiquidationEnv([0, 1], action_levels=21, level_noise=0.2))


def rollout(env, fractions):
    """Step all seeds with the given sell fraction per step (S,) until all are done;
    returns the last step's "next" TensorDict."""
    td = env.reset()
    for f in fractions:
        td["action"] = f[:, None].to(D) if env.cfg.action_levels == 0 else f
        td = env.step(td)
        nxt = td["next"]
        if nxt["done"].all():
            return nxt
        td = env.step_mdp(td)
    return nxt


def test_noise_free_optimal_schedule_costs_E_star():
    """Price noise off (sigma still sets kappa and the risk term): the simulated
    shortfall of the AC schedule is E* up to whole-share rounding."""
    env = LiquidationEnv([0], price_noise=False)
    f = env.model.sell_fractions()
    nxt = rollout(env, [f[k:k + 1] for k in range(60)])
    assert float(nxt["implementation_shortfall"]) == pytest.approx(477_712.60, abs=50)
    assert float(nxt["ac_cost"]) == pytest.approx(U_STAR, abs=50)


def test_one_step_rewards_by_hand():
    """First trade selling 30%: n = 300,000 at 50 - 0.0625 - 2.5e-6 * 300,000 = 49.1875."""
    n, x = 300_000, 700_000
    cost = n * (50 - 49.1875) + LAM * SIGMA2 * x ** 2
    env = LiquidationEnv([0])
    td = env.reset().set("action", torch.tensor([[0.3]], dtype=D))
    out = env.step(td)["next"]
    assert float(out["reward"]) == pytest.approx(-cost / 1e6, rel=1e-12)
    assert float(out["implementation_shortfall"]) == pytest.approx(n * 0.8125, rel=1e-12)
    assert out["observation"][0, -2:].tolist() == pytest.approx([59 / 60, 0.7])
    # utility-ratio: U(x) = eps x + (U* - eps X)(x / X)^2 (E*, V* are eps x plus quadratics in x)
    u = lambda s: EPS * s + (704_723.2174653506 - EPS * X) * (s / X) ** 2  # noqa: E731
    env = LiquidationEnv([0], reward="utility-ratio")
    out = env.step(env.reset().set("action", torch.tensor([[0.3]], dtype=D)))["next"]
    assert float(out["reward"]) == pytest.approx((u(X) - u(x)) / u(X), rel=1e-9)


def test_last_trade_sells_everything_and_levels_are_fractions():
    env = LiquidationEnv([0], trades=3, action_levels=5)     # levels 0, .25, .5, .75, 1
    td = env.reset()
    sold = []
    for a in (1, 2, 0):                                      # 25%, then 50%, then "0%" at the last trade
        td = env.step(td.set("action", torch.tensor([a])))
        sold.append(round(1e6 - float(td["next", "observation"][0, -1]) * 1e6))
        td = env.step_mdp(td)
    assert sold == [250_000, 625_000, 1_000_000]
    env = LiquidationEnv([0], action_levels=5)
    out = env.step(env.reset().set("action", torch.tensor([4])))["next"]
    assert bool(out["terminated"]) and float(out["observation"][0, -1]) == 0.0


def test_partial_reset_leaves_other_seeds_alone():
    env = LiquidationEnv([0, 1])
    td = env.reset()
    for _ in range(3):
        td = env.step_mdp(env.step(td.set("action", torch.full((2, 1), 0.1, dtype=D))))
    before = td["observation"][1].clone()
    out = env.reset(td.clone().set("_reset", torch.tensor([[True], [False]])))
    assert out["observation"][0, -2:].tolist() == [1.0, 1.0] and not out["observation"][0, :6].any()
    assert torch.equal(out["observation"][1], before)
    assert env.t.tolist() == [0, 3] and env.episode.tolist() == [1, 0]


def unimpacted_prices(agent, seeds, episodes=3):
    """Per (seed, episode): the price path with the agent's own permanent impact added
    back, S_k + gamma (X - x_k), i.e. S_0 plus the noise alone."""
    config = resolve_config(env="liquidation", agent=agent, seeds=seeds, episodes=episodes)
    env, pol = build(config)
    paths = {}

    def record(col):
        for i, s in enumerate(env.seeds):
            key = (s, int(env.episode[i]))
            if int(env.t[i]) > 0:  # a step of this episode happened (the env resets only after)
                paths.setdefault(key, []).append(float(env.price[i] + env.model.gamma * (X - env.x[i])))
        return False
    OnlineCollector(env, pol, episodes, progress=False).run(after_step=record)
    return paths


def test_common_random_numbers_across_agents_and_batches():
    """ac-optimal and TWAP (different trades, different episode lengths) see the same price
    noise for the same (seed, episode), alone or in a batch."""
    a = unimpacted_prices("ac-optimal", [0, 1])
    b = unimpacted_prices("twap", [1])
    shared = [k for k in b if k in a]
    assert {k[1] for k in shared} == {0, 1, 2}
    for k in shared:
        n = min(len(a[k]), len(b[k]))
        assert n >= 50 and a[k][:n] == pytest.approx(b[k][:n], abs=1e-9)
    assert a[(0, 1)][:10] != pytest.approx(a[(1, 1)][:10])  # seeds differ


@pytest.mark.parametrize("bad, match", [
    (dict(shares=-5), "shares"), (dict(trades=0), "trades"), (dict(lam=-1e-6), "lam"),
    (dict(horizon=0), "horizon"), (dict(action_levels=1), "action_levels"),
    (dict(level_noise=0.2), "level_noise"), (dict(daily_volume=float("nan")), "daily_volume")])
def test_impossible_settings_are_refused(bad, match):
    with pytest.raises(ValueError, match=match):
        resolve_config(env="liquidation", agent="ac-optimal", **bad)


def test_schedules_refuse_discrete_actions_and_other_envs():
    with pytest.raises(ValueError, match="action_levels=0"):
        resolve_config(env="liquidation", agent="ac-optimal", action_levels=21)
    with pytest.raises(ValueError, match="liquidation"):
        resolve_config(env="square", agent="twap", preset="shaped")


def test_ac_optimal_over_400_episodes_matches_E_and_U():
    """Mean shortfall and ac_cost of the optimum and of TWAP within three standard errors of
    their closed forms; TWAP's cost is about 4.3x U* at about half the shortfall (SPEC 3.2).
    80 seeds x 5 episodes: the same 400 episodes' statistics as 8 x 50 at a tenth of the steps."""
    def within_3_se(df, expected):
        for col, ref in zip(("implementation_shortfall", "ac_cost"), expected):
            se = df[col].std() / math.sqrt(len(df))
            assert abs(df[col].mean() - ref) < 3 * se, (col, df[col].mean(), ref, se)
    opt = run_experiment(resolve_config(env="liquidation", agent="ac-optimal", seeds=80, episodes=5), progress=False)
    assert len(opt) == 400
    within_3_se(opt, (477_712.60, U_STAR))
    assert (opt["return"] * -1e6 - opt["ac_cost"]).abs().max() < 1e-3  # return = -ac_cost / scale
    # TWAP by hand, SPEC 3.2's market (eps 0.0625, gamma 2.5e-7, eta~ 2.375e-6 per day, sigma^2 0.144
    # $^2 per day, tau 1 day): E = eps X + gamma X^2 / 2 + eta~ N (X / N)^2, V = sigma^2 sum_k x_k^2
    X, N = 1e6, 60
    E = 0.0625 * X + 2.5e-7 * X ** 2 / 2 + 2.375e-6 * N * (X / N) ** 2
    U = E + 1e-6 * 0.144 * sum((X * (1 - k / N)) ** 2 for k in range(1, N + 1))
    assert U / U_STAR == pytest.approx(4.3, abs=0.01) and E / 477_712.60 == pytest.approx(0.48, abs=0.01)
    within_3_se(run_experiment(resolve_config(env="liquidation", agent="twap", seeds=80, episodes=5),
                               progress=False), (E, U))


def test_ac_optimal_agent_without_noise_costs_E_star():
    """The agent (not the model) through the runner: it reads the trade count from the
    observation and must sell the schedule's fraction at the right trade."""
    df = run_experiment(resolve_config(env="liquidation", agent="ac-optimal", seeds=[0], episodes=1,
                                       price_noise=False), progress=False)
    assert float(df.implementation_shortfall[0]) == pytest.approx(477_712.60, abs=50)


@pytest.mark.parametrize("market", [{}, dict(trades=6, horizon=6.0, lam=2e-5)])
def test_ac_optimal_agent_trades_the_optimal_list(market):
    """Trade by trade, the agent sells the closed-form list (to whole shares); the short,
    urgent market makes a schedule one trade off visible (its fractions vary)."""
    env, agent = build(resolve_config(env="liquidation", agent="ac-optimal", seeds=[0], episodes=1, **market))
    td, held, sold = env.reset(), X, []
    while not sold or not bool(td["done"]):
        td = env.step(td.set("action", agent.act(td)))
        left = float(td["next", "observation"][0, -1]) * X
        sold.append(held - left)
        held, td = left, env.step_mdp(td)
    expected = env.model.trade_list().tolist()
    assert len(sold) >= len(expected) - 2 and sold == pytest.approx(expected[:len(sold)], abs=2)
    if not market:
        assert sold[0] == pytest.approx(217_778, abs=1)


def test_cost_figure_keeps_every_block_mean_on_its_axis_and_legends_off_the_curves(tmp_path, saved_figures):
    """liquidation_cost.png: a block's mean shortfall below zero (TWAP's, when prices rose) fell
    off the log axis; that panel is linear, the other stays log with at least three dollar
    labels; the legend sits below the panels, not over the curves; titles inside the image."""
    import pandas as pd

    from tests.test_report import fake_run
    from trl_dgpq.analysis import load_run
    from trl_dgpq.envs.liquidation.analysis import figures
    runs = []
    for name, shortfall, cost in (("ac-optimal", [480e3, 470e3, 500e3, 460e3], [700e3, 690e3, 720e3, 710e3]),
                                  ("twap", [350e3, -230e3, 210e3, 280e3], [3.1e6, 2.6e6, 3.0e6, 3.1e6])):
        folder = fake_run(tmp_path / name, "liquidation", {0: [60] * 4}, agent=name)
        df = pd.read_csv(folder / "episodes.csv").assign(implementation_shortfall=shortfall, ac_cost=cost)
        df.to_csv(folder / "episodes.csv", index=False)
        runs.append(load_run(folder))
    figures(runs, ["ac-optimal", "twap"], tmp_path, block=1, title="quick scale (fewer seeds and episodes than "
                                                                     "the seed report)")
    fig = saved_figures["liquidation_cost.png"]
    shortfall, cost = fig.axes[:2]
    assert shortfall.get_yscale() == "linear" and cost.get_yscale() == "log"
    for name in ("liquidation_cost.png", "liquidation_time.png"):
        assert saved_figures.problems(name) == [], name
        drawn = saved_figures[name]
        assert all(ax.get_legend() is None for ax in drawn.axes) and drawn.legends
        legend = drawn.legends[0].get_window_extent()
        assert not any(legend.overlaps(ax.get_window_extent()) for ax in drawn.axes)


def test_cost_figure_draws_fourteen_runs_each_its_own_way(tmp_path, saved_figures):
    """The report's liquidation figure draws 14 runs: matplotlib's 10-colour cycle gave the 11th
    the 1st one's colour (ddpg-course looked like ac-optimal); every run is told apart, in the
    cost figure and the time figure."""
    from tests.test_report import fake_run
    from trl_dgpq.analysis import load_run
    from trl_dgpq.envs.liquidation.analysis import figures
    runs = [load_run(fake_run(tmp_path / f"r{k}", "liquidation", {0: [60] * 2}, agent="twap")) for k in range(14)]
    for run in runs:
        run.df["implementation_shortfall"], run.df["ac_cost"] = 5e5, 7e5
    figures(runs, [f"run {k}" for k in range(14)], tmp_path, block=1, title="t")
    for name in ("liquidation_cost.png", "liquidation_time.png"):
        assert not [p for p in saved_figures.problems(name) if "drawn alike" in p], name
        assert len(saved_figures[name].axes[0].get_lines()) >= 14


def test_drift_is_the_paired_cost_ratio_per_block_by_hand():
    """3 blocks of 2 episodes, one seed: costs 4, 4 | 3, 3 | 6, 2 against an optimum of 2 each
    (and an extra pair the learner lacks): ratios 2, 1.5, 2; the last 2 episodes 8/4 = 2; after
    the first block the worst over the best is 2 / 1.5."""
    import pandas as pd
    from trl_dgpq.envs.liquidation.analysis import drift
    df = pd.DataFrame(dict(seed=0, episode=range(1, 7), ac_cost=[4.0, 4.0, 3.0, 3.0, 6.0, 2.0]))
    ref = pd.DataFrame(dict(seed=0, episode=range(1, 8), ac_cost=[2.0] * 6 + [100.0]))
    got = drift(df, ref, block=2, settle=2, last=2)
    assert got["blocks"] == pytest.approx([2.0, 1.5, 2.0]) and got["last"] == pytest.approx(2.0)
    assert got["worst_over_best"] == pytest.approx(2.0 / 1.5)
    ref.loc[ref.episode == 3, "ac_cost"] = 4.0                  # pairs, not means of separate sets
    assert drift(df, ref, block=2, settle=2, last=2)["blocks"][1] == pytest.approx(6.0 / 6.0)
    own = df.assign(optimal_ac_cost=[2.0, 2.0, 4.0, 2.0, 2.0, 2.0])  # the run's own column: no reference run
    assert drift(own, block=2, settle=2, last=2)["blocks"] == pytest.approx([2.0, 1.0, 2.0])


def test_noise_free_drift_is_the_mean_noise_free_ratio_per_block_by_hand():
    """Two seeds, 3 blocks of 2 episodes: block means 1.1, 1.15, 1.2 (an old checkpoint's NaN left
    out of its block), the last 2 episodes 1.2, the worst after the first block 1.2 / 1.15; the
    defaults are blocks of 500, the first 1,000 episodes left out, the last 1,000; None without
    the column or with nothing in it."""
    import numpy as np
    import pandas as pd
    from trl_dgpq.envs.liquidation.analysis import noise_free_drift
    df = pd.DataFrame(dict(seed=[0] * 6 + [1] * 6, episode=list(range(1, 7)) * 2,
                           noise_free_cost_ratio=[1.2, 1.0, 1.1, 1.1, 1.0, 1.4] + [1.1, 1.1, 1.0, 1.3, 1.3, 1.1]))
    got = noise_free_drift(df, block=2, settle=2, last=2)
    assert got["blocks"] == pytest.approx([1.1, 1.125, 1.2]) and got["last"] == pytest.approx(1.2)
    assert got["worst_over_best"] == pytest.approx(1.2 / 1.125)
    assert math.isnan(noise_free_drift(df, block=2, settle=6, last=2)["worst_over_best"])
    assert noise_free_drift(df.drop(columns="noise_free_cost_ratio")) is None
    assert noise_free_drift(df.assign(noise_free_cost_ratio=np.nan)) is None
    # a run resumed after the column arrived: judged only if every episode after `settle` has it
    # (an early gap, from before the column, is left out of its block)
    resumed = df.assign(noise_free_cost_ratio=[np.nan, 1.0, 1.0, 1.0, 1.0, 1.0, np.nan, 1.2, 1.1, 1.1, 1.1, 1.1])
    assert noise_free_drift(resumed, block=2, settle=2, last=2)["blocks"] == pytest.approx([1.1, 1.05, 1.05])
    late = resumed.assign(noise_free_cost_ratio=resumed.noise_free_cost_ratio.where(resumed.episode != 3))
    assert noise_free_drift(late, block=2, settle=2, last=2) is None
    assert noise_free_drift(late, block=2, settle=4, last=2) is not None   # episode 3 not weighed
    edge = resumed.assign(noise_free_cost_ratio=resumed.noise_free_cost_ratio.where(resumed.episode != 2))
    assert noise_free_drift(edge, block=2, settle=2, last=2) is not None   # episode 2 is `settle`'s own
    four = resumed.assign(noise_free_cost_ratio=resumed.noise_free_cost_ratio.where(resumed.episode != 4))
    assert noise_free_drift(four, block=2, settle=6, last=2) is not None   # the last 2 are 5 and 6
    e = np.arange(1, 3001)
    shift = (e > 2500) / 10 - ((e > 1000) & (e <= 1500)) / 20 - (e <= 1000) / 5   # block 3 the best after 1,000
    long = pd.DataFrame(dict(seed=0, episode=e, noise_free_cost_ratio=1 + (e % 7) / 100 + shift))
    got = noise_free_drift(long)
    means = [float(np.mean(1 + (e[k * 500:(k + 1) * 500] % 7) / 100 + (k == 5) / 10 - (k == 2) / 20 - (k < 2) / 5))
             for k in range(6)]
    assert got["blocks"] == pytest.approx(means, rel=1e-12) and len(got["blocks"]) == 6
    assert got["last"] == pytest.approx(float(np.mean(long.noise_free_cost_ratio[2000:])), rel=1e-12)
    assert got["worst_over_best"] == pytest.approx(max(means[2:]) / min(means[2:]), rel=1e-12)
    # drift's defaults are the same: the paired ratio over an optimum of 1 is the mean
    from trl_dgpq.envs.liquidation.analysis import drift
    paired = drift(long.assign(ac_cost=long.noise_free_cost_ratio, optimal_ac_cost=1.0))
    assert paired["blocks"] == pytest.approx(means, rel=1e-12) and paired["last"] == pytest.approx(got["last"])
    assert paired["worst_over_best"] == pytest.approx(got["worst_over_best"], rel=1e-12)


def test_cost_ratio_pairs_each_episode_with_the_ac_optimum_on_its_prices():
    """optimal_ac_cost is what the ac-optimal agent pays on the same (seed, episode), whatever
    the other agent did before (random sells at random speeds: its episodes differ in length),
    and cost_ratio = 1 + (ac_cost - that) / U*; the optimum's own ratio is 1."""
    opt = run_experiment(resolve_config(env="liquidation", agent="ac-optimal", seeds=[3, 4], episodes=12),
                         progress=False)
    rnd = run_experiment(resolve_config(env="liquidation", agent="random", seeds=[4, 3], episodes=12),
                         progress=False)
    assert rnd.steps.nunique() > 3
    assert opt.optimal_ac_cost.to_numpy() == pytest.approx(opt.ac_cost.to_numpy(), rel=1e-12)
    assert opt.cost_ratio.to_numpy() == pytest.approx([1.0] * len(opt), abs=1e-10)
    pairs = rnd.merge(opt, on=["seed", "episode"], suffixes=("", "_opt"))
    assert len(pairs) == 24
    assert pairs.optimal_ac_cost.to_numpy() == pytest.approx(pairs.ac_cost_opt.to_numpy(), rel=1e-12)
    assert pairs.cost_ratio.to_numpy() == pytest.approx((1 + (pairs.ac_cost - pairs.ac_cost_opt) / U_STAR).to_numpy(),
                                                         rel=1e-6)


@pytest.mark.parametrize("horizon", [2.0, 5.0])      # tau 1, and 2.5 (where sigma^2 tau and sigma^2 / tau differ)
def test_path_cost_by_hand_on_two_trades(horizon):
    env = LiquidationEnv(seeds=[0], trades=2, horizon=horizon, shares=1000)
    m, s0 = env.model, 50.0
    assert m.tau == horizon / 2
    a = m.eta / m.tau
    step = math.sqrt(m.sigma2 * m.tau)
    first = 600 * (m.eps + a * 600)                                  # at S_0: no noise before the first trade
    second = 400 * (s0 - (s0 + step * 0.5 - m.gamma * 600 - m.eps - a * 400))
    risk = m.lam * m.sigma2 * m.tau * 400 ** 2                       # held after the first trade; 0 after the last
    got = env.path_cost(torch.tensor([600.0, 400.0], dtype=torch.float64),
                        torch.tensor([[0.5, -1.0], [0.0, 0.0]], dtype=torch.float64))
    assert got[0].item() == pytest.approx(first + second + risk, rel=1e-12)
    assert got[1].item() == pytest.approx(first + 400 * (m.gamma * 600 + m.eps + a * 400) + risk, rel=1e-12)


def test_a_checkpoint_from_before_optimal_ac_cost_loads_with_it_from_its_prices():
    env = LiquidationEnv(seeds=[0, 1])
    env.reset()
    state = env.state_dict()
    old = {k: v for k, v in state.items() if k != "optimal_ac_cost"}
    fresh = LiquidationEnv(seeds=[0, 1])
    fresh.load_state_dict(old)
    assert torch.equal(fresh.optimal_ac_cost, state["optimal_ac_cost"]) and bool((state["optimal_ac_cost"] > 0).all())


def test_impact_reward_by_hand_is_the_shortfall_without_its_price_noise_term():
    """reward "impact" on three trades two days apart (600 of 1,000 shares, none, the rest) by
    hand: each trade's spread and temporary impact, its permanent impact on what is still held,
    the risk term; the same on every price path (two seeds). The shortfall's return on the same
    path differs by exactly sigma sqrt(tau) (xi_1 x_1 + xi_2 x_2), the mark-to-market of the 400
    shares held over the first two intervals."""
    kw = dict(seeds=[0, 1], trades=3, horizon=6.0, shares=1000, reward_scale=1.0)
    m = LiquidationEnv(**kw).model
    assert m.tau == 2.0
    a, risk = m.eta / m.tau, m.lam * m.sigma2 * m.tau * 400 ** 2
    by_hand = [600 * (m.eps + a * 600) + m.gamma * 600 * 400 + risk, risk, 400 * (m.eps + a * 400)]
    returns = {}
    for reward in ("impact", "shortfall"):
        env = LiquidationEnv(**kw, reward=reward)
        td = env.reset()
        got = []
        for fraction in (0.6, 0.0, 0.0):                   # the last trade sells the rest
            td = env.step(td.set("action", torch.full((2, 1), fraction, dtype=D)))
            got.append(td["next", "reward"][:, 0])
            td = env.step_mdp(td)
        returns[reward] = sum(got)
        # whatever the reward, the episode's noise-free ac_cost is the hand sum, on every path
        assert td["noise_free_ac_cost"].tolist() == pytest.approx([sum(by_hand)] * 2, rel=1e-12)
        if reward == "impact":
            for step, cost in zip(got, by_hand):
                assert step.tolist() == pytest.approx([-cost] * 2, rel=1e-12)
        xi = env.xi[:, :2].sum(-1)
    assert xi[0] != xi[1]
    assert (returns["shortfall"] - returns["impact"]).tolist() == pytest.approx(
        (math.sqrt(m.sigma2 * m.tau) * xi * 400).tolist(), rel=1e-9)
    assert (td["noise_free_ac_cost"] - td["ac_cost"]).tolist() == pytest.approx(
        (math.sqrt(m.sigma2 * m.tau) * xi * 400).tolist(), rel=1e-9)


def test_noise_free_cost_ratio_is_one_for_the_optimum_and_has_the_cost_ratios_mean():
    """The AC schedule's noise-free ac_cost is the same every episode, its expected ac_cost, and
    its ratio is 1 exactly; TWAP's is the same every episode and is, by hand, its impact and
    risk terms (n = X / N each trade, x_k = X (N - k) / N held after trade k) less the
    optimum's, over U*; averaged over 400 seeds its cost_ratio agrees with that within the noise."""
    opt = run_experiment(resolve_config(env="liquidation", agent="ac-optimal", seeds=[3, 4], episodes=3),
                         progress=False)
    assert opt.noise_free_cost_ratio.to_numpy() == pytest.approx([1.0] * 6, abs=1e-12)
    assert opt.noise_free_ac_cost.to_numpy() == pytest.approx([U_STAR] * 6, rel=1e-4)   # U* up to rounding
    assert opt.noise_free_ac_cost.nunique() == 1 and opt.ac_cost.nunique() == 6
    env = LiquidationEnv(seeds=list(range(400)), shares=600_000)  # 10,000 a trade: whole shares
    m, big_n, big_x, u_star = env.model, env.cfg.trades, env.cfg.shares, float(env.u_star)
    n = big_x / big_n
    held = [big_x * (big_n - k) / big_n for k in range(1, big_n + 1)]
    by_hand = sum(n * (m.eps + m.eta / m.tau * n) + m.gamma * n * x + m.lam * m.sigma2 * m.tau * x * x for x in held)
    optimum = float(env.path_cost(env.optimal_trades, torch.zeros(1, big_n, dtype=D))[0])
    td = env.reset()
    for k in range(big_n):
        td = env.step(td.set("action", torch.full((400, 1), 1 / (big_n - k), dtype=D)))
        td = env.step_mdp(td)
    ratio = td["noise_free_cost_ratio"].numpy()
    assert ratio == pytest.approx([1 + (by_hand - optimum) / u_star] * 400, rel=1e-9) and ratio[0] > 2
    paired = td["cost_ratio"].numpy()
    assert abs(paired.mean() - ratio[0]) < 3 * paired.std() / math.sqrt(400) and paired.std() > 0.1


def test_a_checkpoint_from_before_noise_free_ac_cost_loads_with_it_where_it_is_known():
    """Zero for a seed at its episode's start, NaN (not a wrong number) for one midway."""
    env = LiquidationEnv(seeds=[0, 1])
    td = env.reset()
    env.step(td.set("action", torch.full((2, 1), 0.1, dtype=D)))
    state = env.state_dict()
    state["t"] = torch.tensor([0, 1])
    fresh = LiquidationEnv(seeds=[0, 1])
    fresh.load_state_dict({k: v for k, v in state.items() if k != "noise_free_ac_cost"})
    assert fresh.noise_free_ac_cost[0].item() == 0.0 and math.isnan(fresh.noise_free_ac_cost[1].item())


def test_impact_reward_has_the_shortfalls_mean_return_for_a_fixed_schedule():
    """TWAP over 400 seeds' first episodes: the two rewards' mean returns agree within the noise
    term's standard error, and without price noise they are equal seed by seed."""
    def returns(reward, **kw):
        env = LiquidationEnv(seeds=list(range(400)), reward=reward, **kw)
        td, total = env.reset(), torch.zeros(400, dtype=D)
        for k in range(env.cfg.trades):                     # 1/N of the shares each trade
            td = env.step(td.set("action", torch.full((400, 1), 1 / (env.cfg.trades - k), dtype=D)))
            total += td["next", "reward"][:, 0]
            td = env.step_mdp(td)
        return total.numpy()
    assert returns("impact", price_noise=False) == pytest.approx(returns("shortfall", price_noise=False), rel=1e-12)
    gap = returns("shortfall") - returns("impact")
    assert abs(gap.mean()) < 3 * gap.std() / math.sqrt(len(gap)) and gap.std() > 0.1


def test_pace_is_shares_left_over_trades_left_and_off_by_default():
    assert LiquidationEnv([0]).reset()["observation"].shape == (1, 8)
    env = LiquidationEnv([0], trades=3, shares=1000, pace=True, action_levels=5)
    check_env_specs(env)
    td = env.reset()
    seen = [td["observation"][0, -1].item()]
    for a in (2, 2, 0):                                   # half, half of the rest, the rest
        td = env.step(td.set("action", torch.tensor([a])))
        seen.append(td["next", "observation"][0, -1].item())
        td = env.step_mdp(td)
    assert seen == pytest.approx([1 / 3, 0.5 / 2, 0.25 / 1, 0.0])


def test_the_optimal_cost_to_go_is_lipschitz_in_shares_and_pace_not_in_time():
    """Why ``pace`` (docs/domains/liquidation.md, "Drift"): V*(x, k), the AC optimum's cost of
    selling x (of X) in k trades ($M; k = 1 sells at once), changes by at most ~2.5 per unit of
    L1 distance in (x, x / k), but by ~69 in (k / N, x), the state DGPQ saw: an envelope with
    L_Q below that is not optimistic near the horizon's end."""
    base = ACModel.from_config(LiquidationConfig())

    def v(x, k):
        if k == 1:
            n = x * base.shares
            return (base.eps * n + base.eta / base.tau * n * n) / 1e6
        return ACModel(**{**base.__dict__, "shares": x * base.shares, "trades": k, "horizon": k * base.tau}).utility() / 1e6
    x, k = torch.meshgrid(torch.arange(1, 21, dtype=D) / 20, torch.arange(1, 61, dtype=D), indexing="ij")
    x, k = x.flatten(), k.flatten()
    value = torch.tensor([v(a, int(b)) for a, b in zip(x.tolist(), k.tolist())], dtype=D)
    assert value.max().item() == pytest.approx(2.5625) and v(1.0, 60) == pytest.approx(U_STAR / 1e6)

    def lipschitz(*coords):
        f = torch.stack(coords, -1)
        d = torch.cdist(f, f, p=1)
        return ((value[:, None] - value[None, :]).abs() / d.fill_diagonal_(torch.inf)).max().item()
    assert 2.4 < lipschitz(x, x / k) < 2.6
    assert lipschitz(k / 60, x) > 60


# Q̂ never overwritten (every action ties: the seeds end at 4-12 trades); every action at the start overwritten
@pytest.mark.parametrize("sigma_tol2, levels", [(1e-12, 21), (0.01, 3)])
def test_start_optimism_is_qhat_at_the_start_less_what_its_greedy_episode_collects(tmp_path, sigma_tol2, levels):
    """Q̂ at the start state by hand (Eq. 7 over the checkpoint's pairs: min(V_max, mu_i + L_Q |s - s_i|_1),
    the greedy action's the largest); the value and trades are those of evaluate's one episode per seed
    (eval.csv, the collector's own sums, seeds ending at different trades); optimism is the difference."""
    from trl_dgpq.collectors.evaluate import evaluate, restore
    from trl_dgpq.commands import train
    from trl_dgpq.envs.liquidation.analysis import start_optimism
    out = tmp_path / "run"
    assert train.main(["--env", "liquidation", "--agent", "dgpq", "--reward", "impact", "--trades", "12",
                       "--action-levels", str(levels), "--seeds", "4,1,6,2,9", "--episodes", "10",
                       "--set", f"sigma_tol2={sigma_tol2}",
                       "--out", str(out), "--no-progress"]) == 0
    got = start_optimism(out)
    ev = evaluate(out, episodes=1).set_index("seed").loc[[4, 1, 6, 2, 9]]
    assert list(got.seed) == [4, 1, 6, 2, 9]
    assert got.value.tolist() == pytest.approx(ev["return"].tolist(), abs=1e-6)
    assert got.trades.tolist() == ev.steps.tolist()
    config, env, agent, state = restore(out)
    env.for_evaluation()
    s0 = agent.features(env.reset()["observation"])
    mu, s = state["agent"]["qhat"]["mu"], state["agent"]["qhat"]["s"]          # (S, A, capacity[, dim])
    envelope = (mu + agent.cfg.lipschitz * (s - s0[:, None, None, :]).abs().sum(-1)).amin(-1)
    by_hand = envelope.clamp_max(agent.cfg.v_max).amax(-1)
    assert got.qhat_start.tolist() == pytest.approx(by_hand.tolist(), abs=1e-12)
    if sigma_tol2 < 1e-6:
        assert (got.qhat_pairs == 0).all() and (got.qhat_start == agent.cfg.v_max).all() and ev.steps.nunique() > 2
    else:
        assert (got.qhat_pairs > 0).all() and (got.qhat_start < agent.cfg.v_max).all()
    assert got.optimism.tolist() == pytest.approx((got.qhat_start - got.value).tolist(), abs=1e-12)
    assert got.per_trade.tolist() == pytest.approx((got.optimism / got.trades).tolist(), abs=1e-12)
    assert (got.eps1 == agent.cfg.eps1).all()


def test_start_optimism_refuses_a_run_without_qhat(tmp_path):
    from trl_dgpq.commands import train
    from trl_dgpq.envs.liquidation.analysis import start_optimism
    assert train.main(["--env", "liquidation", "--agent", "twap", "--trades", "4", "--seeds", "1", "--episodes", "1",
                       "--out", str(tmp_path / "twap"), "--no-progress"]) == 0
    with pytest.raises(ValueError, match="is not a DGPQ run"):
        start_optimism(tmp_path / "twap")


@pytest.mark.filterwarnings("ignore:.*found in sys.modules")   # runpy: the module is imported already
@pytest.mark.parametrize("keep", [True, False])
def test_the_analysis_command_prints_the_blocks_and_says_when_a_run_keeps_no_checkpoint(tmp_path, capsys, keep):
    """python -m trl_dgpq.envs.liquidation.analysis RUN: the blocks, then Q̂ at the start per seed; an
    ended tuning trial keeps its rows but no checkpoint: Q̂ at the start said to be unmeasured, in one line."""
    import runpy
    import sys

    from trl_dgpq.commands import train
    out = tmp_path / "run"
    assert train.main(["--env", "liquidation", "--agent", "dgpq", "--trades", "4", "--action-levels", "3",
                       "--seeds", "1", "--episodes", "3", "--out", str(out), "--no-progress"]) == 0
    if not keep:
        (out / "checkpoint.pt").unlink()
    capsys.readouterr()
    argv = sys.argv
    try:
        sys.argv = ["analysis", str(out)]
        runpy.run_module("trl_dgpq.envs.liquidation.analysis", run_name="__main__")
    finally:
        sys.argv = argv
    lines = capsys.readouterr().out.strip().splitlines()
    assert lines[0].startswith("ac_cost / optimum per 500 episodes: ")
    if keep:
        assert lines[-3] == "Q̂ at the start state against what its greedy policy collects:"
        assert lines[-2].split()[:3] == ["seed", "eps1", "qhat_start"] and lines[-1].split()[0] == "0"
    else:
        assert lines[-1] == f"Q̂ at the start state: not measured, {out} keeps no checkpoint.pt"
