"""envs/liquidation/analysis.py by hand on made-up runs, each function called at test time (the
module's CLAIMS are built at import): train.py's summary, the cost and time figures read back, the
comparison table line by line, the holdings figure and its data, the claims' words and measures,
the REPORT.md section; and `holdings` of a DGPQ run selling out early (the schedules' closed forms:
test_evaluate)."""
import json
import lzma
import math
from pathlib import Path

import matplotlib.colors
import numpy as np
import pandas as pd
import pytest

from trl_dgpq.analysis.claims import Agrees, Bound
from trl_dgpq.analysis.runs import Run
from trl_dgpq.envs.liquidation import analysis as la
from trl_dgpq.envs.liquidation.almgren_chriss import ACModel
from trl_dgpq.envs.liquidation.env import LiquidationConfig

DEFAULT = ACModel.from_config(LiquidationConfig())   # U* $704,723, E* $477,713 (test_liquidation's reference)


def run(agent, episodes=4, seeds=(0, 1), gamma=None, env=None, path="runs/x", **columns):
    """A liquidation run: each column a function of (seed, episode), or a constant."""
    rows = [dict(seed=s, episode=e) for s in seeds for e in range(1, episodes + 1)]
    df = pd.DataFrame(rows)
    for name, f in columns.items():
        df[name] = [f(s, e) for s, e in zip(df.seed, df.episode)] if callable(f) else f
    agent_cfg = {} if gamma is None else {"gamma": gamma}
    config = {"run": {"env": "liquidation", "agent": agent, "preset": "p", "seeds": list(seeds)},
              "env": {"reward": "shortfall", **(env or {})}, "agent": agent_cfg}
    return Run(Path(path), df, config)


# ------------------------------------------------------------------ what train.py prints
def test_the_summary_is_the_last_100_episodes_means():
    """Episodes 1-150 of two seeds: the last 100 are 51-150, mean episode 100.5."""
    r = run("ddpg", episodes=150, ac_cost=lambda s, e: 1000.0 * e, implementation_shortfall=lambda s, e: 500.0 * e,
            cost_ratio=lambda s, e: e / 100)
    assert la.summary(r.df) == [
        "last 100 episodes: mean ac_cost $100,500, mean implementation shortfall $50,250",
        "last 100 episodes: mean cost_ratio (E[ac_cost] / U*, paired with the AC optimum on the same prices; the "
        "measure plot, report and evaluate show): 1.0050"]
    assert la.summary(r.df.drop(columns="cost_ratio")) == la.summary(r.df)[:1]   # a run from before the column
    short = run("ddpg", episodes=3, ac_cost=1.0, implementation_shortfall=2.0)
    assert la.summary(short.df) == ["last 3 episodes: mean ac_cost $1, mean implementation shortfall $2"]


# ------------------------------------------------------------------ the figures
def test_a_panel_is_titled_by_its_discount_and_says_where_the_schedules_are():
    assert la.panel_title(None, 2, True) == ""
    assert la.panel_title(0.99, 1, True) == "learners with gamma = 0.99"
    assert la.panel_title(0.5, 2, True) == "learners with gamma = 0.5 (schedules in each panel)"
    assert la.panel_title(0.5, 2, False) == "learners with gamma = 0.5"


def test_the_cost_axis_is_log_in_dollars_unless_a_mean_is_not_positive():
    import matplotlib.pyplot as plt
    fig, (a, b) = plt.subplots(1, 2)
    la.cost_axis(a, [2.0, 3e5])
    assert a.get_yscale() == "log" and a.get_lines() == []
    assert a.yaxis.get_major_formatter()(2.5e6, 0) == "$2.5M"
    la.cost_axis(b, [3e5, 0.0])                           # a block's mean at 0: the log axis would drop it
    assert b.get_yscale() == "linear"
    assert b.yaxis.get_major_formatter()(-2e5, 0) == "-$200k"
    zero, = b.get_lines()
    assert list(zero.get_ydata()) == [0, 0] and zero.get_color() == "0.5" and zero.get_linewidth() == 0.6
    plt.close(fig)


def three_runs(tmp_path):
    """DGPQ at gamma 0.99, DDPG at 0.9, the AC optimum (no discount): 5 episodes of 2 seeds; a
    run's shortfall is k x 1,500 x its episode's mean over seeds, its ac_cost twice that, its
    wall time k ms x (seed + 1)."""
    out = []
    for k, (agent, gamma) in enumerate((("dgpq", 0.99), ("ddpg", 0.9), ("ac-optimal", None)), start=1):
        out.append(run(agent, episodes=5, gamma=gamma, path=tmp_path / agent,
                       implementation_shortfall=lambda s, e, k=k: k * 1000.0 * (s + 1) * e,
                       ac_cost=lambda s, e, k=k: k * 2000.0 * (s + 1) * e,
                       wall_s=lambda s, e, k=k: k * 1e-3 * (s + 1), steps=60))
    return out


def test_the_cost_figure_draws_block_means_a_panel_per_discount_with_the_schedules_in_each(tmp_path, drawn):
    """Blocks of 2 over 5 episodes: episodes 1-2, 3-4 and 5, drawn at 2, 4 and 6; means over both
    seeds (1.5 x the seed-0 value) of episodes 1.5, 3.5 and 5."""
    runs = three_runs(tmp_path)
    written = la.figures(runs, ["DGPQ", "DDPG", "optimum"], tmp_path, block=2, title="a title")
    assert written == [tmp_path / "liquidation_cost.png", tmp_path / "liquidation_time.png",
                       tmp_path / "comparison.md"]
    assert (tmp_path / "comparison.md").read_text() == la.comparison_table(runs, ["DGPQ", "DDPG", "optimum"], 1000)
    cost, title = drawn["liquidation_cost.png"]
    assert title == "a title" and len(cost.axes) == 4
    (s90, s99), (c90, c99) = np.array(cost.axes).reshape(2, 2)      # columns: gamma 0.9, then 0.99
    for ax, who in ((s90, ("DDPG", "optimum")), (s99, ("DGPQ", "optimum")), (c90, ("DDPG", "optimum")),
                    (c99, ("DGPQ", "optimum"))):
        lines = [ln for ln in ax.get_lines() if not ln.get_label().startswith("_")]
        assert [ln.get_label() for ln in lines] == list(who)
        k = {"DGPQ": 1, "DDPG": 2, "optimum": 3}
        per = 1500.0 if ax in (s90, s99) else 3000.0
        for line in lines:
            assert list(line.get_xdata()) == [2, 4, 6] and line.get_marker() == "None"
            assert list(line.get_ydata()) == pytest.approx([k[line.get_label()] * per * e for e in (1.5, 3.5, 5)])
        ref = [ln for ln in ax.get_lines() if ln.get_label().startswith("_")]
        want = DEFAULT.expected_shortfall() if ax in (s90, s99) else DEFAULT.utility()
        assert [list(r.get_ydata()) for r in ref] == [[pytest.approx(want)] * 2]
        assert ref[0].get_linestyle() == "--" and ref[0].get_color() == "k"
        assert ax.get_yscale() == "log"
    assert s90.get_title() == c90.get_title() == "learners with gamma = 0.9 (schedules in each panel)"
    assert s99.get_title() == "learners with gamma = 0.99 (schedules in each panel)"
    assert s90.get_ylabel() == "mean implementation shortfall ($)"
    assert c99.get_ylabel() == "mean ac_cost = shortfall + risk term ($)"
    assert c90.get_xlabel() == c99.get_xlabel() == "episode (mean of each block of up to 2)"
    # each run keeps its own look in every panel (a panel's own cycle would restart)
    look = lambda ax, label: next((ln.get_color(), ln.get_linestyle()) for ln in ax.get_lines()  # noqa: E731
                                  if ln.get_label() == label)
    assert look(s90, "optimum") == look(s99, "optimum") != look(s90, "DDPG")
    assert look(s99, "DGPQ") != look(s90, "DDPG")
    assert tuple(cost.get_size_inches()) == pytest.approx((10.4, 7.4))
    assert type(cost.get_layout_engine()).__name__ == "ConstrainedLayoutEngine"
    assert s90.get_shared_x_axes().joined(s90, c90) and s90.get_shared_x_axes().joined(s90, c99)
    legend, = cost.legends
    handles = legend.legend_handles
    assert [(h.get_color(), h.get_linestyle()) for h in handles] == [
        look(s90, "DDPG"), look(s90, "optimum"), look(s99, "DGPQ"), ("k", "--")]
    assert [t.get_text() for t in legend.get_texts()] == [
        "DDPG", "optimum", "DGPQ",
        f"AC optimum: E* = \\${DEFAULT.expected_shortfall():,.0f} (top), U* = \\${DEFAULT.utility():,.0f} (bottom)"]
    assert legend._ncols == 4

    time, title = drawn["liquidation_time.png"]
    t90, t99 = time.axes
    assert tuple(time.get_size_inches()) == pytest.approx((10.4, 4.0))
    assert type(time.get_layout_engine()).__name__ == "ConstrainedLayoutEngine"
    tlegend, = time.legends
    assert [t.get_text() for t in tlegend.get_texts()] == ["DDPG", "optimum", "DGPQ"] and tlegend._ncols == 4
    assert [(h.get_color(), h.get_linestyle()) for h in tlegend.legend_handles] == [
        look(s90, "DDPG"), look(s90, "optimum"), look(s99, "DGPQ")]
    for ax, cost_ax in ((t90, s90), (t99, s99)):
        assert ax.get_yscale() == "log" and ax.get_xlabel() == "episode"
        assert ax.get_ylabel() == "wall ms per episode, per seed"
        for line in ax.get_lines():
            k = {"DGPQ": 1, "DDPG": 2, "optimum": 3}[line.get_label()]
            assert list(line.get_xdata()) == [2, 4, 6]
            assert list(line.get_ydata()) == pytest.approx([k * 1.5] * 3)       # ms: the mean of k and 2k
            assert (line.get_color(), line.get_linestyle()) == look(cost_ax, line.get_label())
    assert t90.get_title() == "learners with gamma = 0.9 (schedules in each panel)"
    # the time figure's legend holds each run's own line (not the figure's lines in turn: the
    # schedule, drawn in both panels, first)
    la.figures(runs[::-1], ["optimum", "DDPG", "DGPQ"], tmp_path, block=2)
    time = drawn["liquidation_time.png"][0]
    dgpq = next(ln for ln in time.axes[1].get_lines() if ln.get_label() == "DGPQ")
    assert time.legends[0].legend_handles[2].get_color() == dgpq.get_color()
    assert title == "a title"


def test_a_run_shorter_than_a_block_is_one_point_and_few_blocks_get_markers(tmp_path, drawn):
    """5 episodes: blocks of 10 give one point at episode 5; blocks of 3 give two, at 3 and 6, drawn
    with markers; one discount: one panel, titled by it, without the note on schedules."""
    r = run("ddpg", episodes=5, gamma=0.5, path=tmp_path / "r", implementation_shortfall=lambda s, e: 1.0 * e,
            ac_cost=lambda s, e: 2.0 * e, wall_s=1e-3, steps=60)
    la.figures([r], ["one"], tmp_path, block=10)
    (ax,), _ = np.array(drawn["liquidation_cost.png"][0].axes).reshape(2, 1)
    line = next(ln for ln in ax.get_lines() if ln.get_label() == "one")
    assert list(line.get_xdata()) == [5] and list(line.get_ydata()) == [3.0] and line.get_marker() == "o"
    assert ax.get_title() == "learners with gamma = 0.5"
    la.figures([r], ["one"], tmp_path, block=3)
    ax = drawn["liquidation_cost.png"][0].axes[0]
    line = next(ln for ln in ax.get_lines() if ln.get_label() == "one")
    assert list(line.get_xdata()) == [3, 6] and list(line.get_ydata()) == [2.0, 4.5] and line.get_marker() == "o"
    opt = run("ac-optimal", episodes=5, path=tmp_path / "o", implementation_shortfall=1.0, ac_cost=1.0,
              wall_s=1e-3, steps=60)
    la.figures([opt], ["opt"], tmp_path, block=1)
    assert drawn["liquidation_cost.png"][0].axes[0].get_title() == ""      # no learner: no discount


def test_learners_alone_get_no_note_on_schedules_and_every_runs_means_decide_the_axis(tmp_path, drawn, monkeypatch):
    """Four learners over two discounts (no schedule): panels titled without the note, the legend in
    4 columns for its 5 entries; the first run's block mean below 0 makes its panel linear though the
    runs after it are positive; the defaults: blocks of 100, no title; the holdings figure, when drawn,
    returned last, with the title."""
    asked = []
    monkeypatch.setattr(la, "holdings_figure", lambda runs, labels, out, title: asked.append(title) or out / "h.png")
    runs = [run("dgpq", episodes=200, gamma=g, path=tmp_path / f"r{i}", wall_s=1e-3, steps=60, ac_cost=1.0,
                implementation_shortfall=(lambda s, e: -1.0) if i == 0 else 5.0)
            for i, g in enumerate((0.9, 0.99, 0.9, 0.99))]
    assert la.figures(runs, list("abcd"), tmp_path)[-1] == tmp_path / "h.png" and asked == [""]
    cost, title = drawn["liquidation_cost.png"]
    assert title == ""
    s90, s99, c90, c99 = cost.axes
    assert s90.get_title() == "learners with gamma = 0.9" and s99.get_title() == "learners with gamma = 0.99"
    assert s90.get_yscale() == "linear" and s99.get_yscale() == "log" and c90.get_yscale() == "log"
    line = next(ln for ln in s90.get_lines() if ln.get_label() == "a")
    assert list(line.get_xdata()) == [100, 200]                             # blocks of 100
    assert cost.legends[0]._ncols == 4 and len(cost.legends[0].get_texts()) == 5
    la.figures(runs, list("abcd"), tmp_path, title="T")
    assert asked[-1] == "T"


# ------------------------------------------------------------------ the comparison table
def table_runs():
    """DGPQ on the impact reward (2 seeds; ac_cost 150 then 120 from episode 3), DDPG (seed 0 only;
    ac_cost 200, shortfall 40) and the optimum (ac_cost 100, shortfall 50), 4 episodes."""
    dgpq = run("dgpq", gamma=0.99, env={"reward": "impact"}, ac_cost=lambda s, e: 150.0 if e < 3 else 120.0,
               implementation_shortfall=lambda s, e: 75.0 if e < 3 else 60.0, wall_s=0.02)
    ddpg = run("ddpg", gamma=0.9, seeds=(0,), ac_cost=200.0, implementation_shortfall=40.0,
               wall_s=lambda s, e: 0.01 * e)
    opt = run("ac-optimal", ac_cost=100.0, implementation_shortfall=50.0, wall_s=0.01)
    return [dgpq, ddpg, opt], ["dgpq", "ddpg", "opt"]


HEADER = ("| run | reward | gamma | seeds x episodes | episodes used | mean ac_cost ($) | ac_cost / optimum's "
          "(ratio of means, paired) | mean shortfall ($) | shortfall / optimum's (ratio of means, paired) | s per "
          "episode per seed |\n|---|---|---|---|---|---|---|---|---|---|\n")


def note(last):
    return (f"\n\nEach run's last {last} episodes, or all it has, grouped by the reward it learned from (a learner is "
            "compared with another only on the same reward; `impact` and `utility-ratio` use the AC model, and the "
            "ac-optimal schedule is its closed form). Ratios: mean over the (seed, episode) pairs it shares with the "
            "ac-optimal run, divided by ac-optimal's mean over the same pairs (same price paths).\n")


def test_the_comparison_table_by_hand_grouped_by_reward_with_ratios_paired_with_the_optimum():
    runs, labels = table_runs()
    assert la.comparison_table(runs, labels, 2) == HEADER + "\n".join([
        "| ddpg | shortfall | 0.9 | 1 x 4 | last 2 | 200 | 2.000 | 40 | 0.800 | 0.025 |",
        "| opt | shortfall (uses the model) | – | 2 x 4 | last 2 | 100 | 1.000 | 50 | 1.000 | 0.01 |",
        "| dgpq | impact (uses the model) | 0.99 | 2 x 4 | last 2 | 120 | 1.200 | 60 | 1.200 | 0.02 |"]) + note(2)
    assert la.comparison_table(runs, labels, 4) == HEADER + "\n".join([
        "| ddpg | shortfall | 0.9 | 1 x 4 | all | 200 | 2.000 | 40 | 0.800 | 0.025 |",
        "| opt | shortfall (uses the model) | – | 2 x 4 | all | 100 | 1.000 | 50 | 1.000 | 0.01 |",
        "| dgpq | impact (uses the model) | 0.99 | 2 x 4 | all | 135 | 1.350 | 68 | 1.350 | 0.02 |"]) + note(4)
    # without the optimum (or no pair shared with it) there is no ratio; the utility-ratio reward sorts after impact
    util = run("ddpg", gamma=0.9, env={"reward": "utility-ratio"}, ac_cost=3e6, implementation_shortfall=1e6,
               wall_s=1.0)
    apart = run("ac-optimal", seeds=(7,), ac_cost=1.0, implementation_shortfall=1.0, wall_s=1.0)
    assert la.comparison_table([util, runs[0], apart], ["u", "dgpq", "opt7"], 3).splitlines()[2:5] == [
        "| opt7 | shortfall (uses the model) | – | 1 x 4 | last 3 | 1 | 1.000 | 1 | 1.000 | 1 |",
        "| dgpq | impact (uses the model) | 0.99 | 2 x 4 | last 3 | 130 | – | 65 | – | 0.02 |",
        "| u | utility-ratio (uses the model) | 0.9 | 2 x 4 | last 3 | 3,000,000 | – | 1,000,000 | – | 1 |"]
    assert "| 120 | – | 60 | – |" in la.comparison_table(runs[:2], labels[:2], 2)


# ------------------------------------------------------------------ the holdings figure
def test_the_holdings_figure_draws_each_learners_median_and_iqr_beside_the_optimum_and_twap(
        tmp_path, monkeypatch, saved_figures):
    """Two learners with checkpoints (holdings stubbed: five episodes each), a schedule left out;
    what is drawn is kept as holdings.json.xz, and a rebuild of a publication draws it again from
    that file; without a checkpoint and outside a publication there is no figure."""
    import trl_dgpq.collectors.evaluate as evaluate
    runs, labels = table_runs()
    N = 60
    drawn = {"dgpq": np.linspace(1, 0, N + 1)[None].repeat(5, 0) * np.arange(1, 6)[:, None] / 5,
             "ddpg": np.zeros((5, N + 1))}
    asked = []
    monkeypatch.setattr(evaluate, "job_folders", lambda path: [path])
    monkeypatch.setattr(la, "holdings", lambda path, episodes: asked.append((path, episodes)) or
                        drawn[path.name])
    twap = run("twap", ac_cost=1.0, implementation_shortfall=1.0, wall_s=1.0, path="twap")
    runs, labels = runs + [twap], labels + ["twap"]
    runs[0].path, runs[1].path, runs[2].path = Path("dgpq"), Path("ddpg"), Path("opt")
    runs[1].config["env"]["trades"] = 7                                   # the market is the first run's
    out = tmp_path / "pub" / "liquidation"
    out.mkdir(parents=True)
    assert la.holdings_figure(runs, labels, out, episodes=5, title="t") == out / "holdings.png"
    assert asked == [(Path("dgpq"), 5), (Path("ddpg"), 5)]                     # the schedules are not learners
    with lzma.open(out / "holdings.json.xz", "rt") as f:
        assert json.load(f) == {k: v.tolist() for k, v in drawn.items()}
    fig = saved_figures["holdings.png"]
    ax, = fig.axes
    assert fig._suptitle.get_text() == "t"
    lines = {ln.get_label(): ln for ln in ax.get_lines()}
    assert list(lines) == ["dgpq (5 evaluation episodes)", "ddpg (5 evaluation episodes)", "Almgren-Chriss optimum",
                           "TWAP"]
    k = np.arange(N + 1)
    assert list(lines["dgpq (5 evaluation episodes)"].get_xdata()) == list(k)
    assert list(lines["dgpq (5 evaluation episodes)"].get_ydata()) == pytest.approx(0.6 * (1 - k / N))  # the median
    band = ax.collections[0].get_paths()[0].vertices                              # IQR: 0.4 and 0.8 of the line
    assert sorted(set(band[band[:, 0] == N / 2, 1].round(12))) == [0.2, 0.4]
    assert list(lines["Almgren-Chriss optimum"].get_ydata()) == pytest.approx(
        (DEFAULT.holdings() / DEFAULT.shares).tolist())
    assert list(lines["TWAP"].get_ydata()) == pytest.approx(1 - k / N)
    assert list(lines["TWAP"].get_xdata()) == list(k) and list(lines["Almgren-Chriss optimum"].get_xdata()) == list(k)
    assert (lines["TWAP"].get_linestyle(), lines["TWAP"].get_color()) == (":", "0.4")
    assert (lines["Almgren-Chriss optimum"].get_linestyle(), lines["Almgren-Chriss optimum"].get_color()) == ("--", "k")
    assert [ln.get_linewidth() for ln in lines.values()] == [1.4, 1.4, 1.2, 1.2]
    for band, line in zip(ax.collections, list(lines.values())[:2]):
        assert list(band.get_facecolor()[0][:3]) == pytest.approx(matplotlib.colors.to_rgb(line.get_color()))
    assert tuple(fig.get_size_inches()) == pytest.approx((6.4, 4.2))
    assert ax.title.get_fontsize() == 9 and ax.get_legend().get_texts()[0].get_fontsize() == 7
    assert ax.get_xlabel() == "trade k" and ax.get_ylabel() == "holdings x_k / X (median; band: IQR)"
    assert ax.get_title() == "what each learner sells, exploration off" and ax.get_legend() is not None

    # a rebuild: no checkpoint, the data file read back, but only inside a publication
    monkeypatch.setattr(evaluate, "job_folders", lambda path: [])
    assert la.holdings_figure(runs, labels, out) is None
    from trl_dgpq.analysis.published import DATA, MANIFEST
    (tmp_path / "pub" / DATA).mkdir()
    (tmp_path / "pub" / DATA / MANIFEST).write_text("{}")
    del saved_figures["holdings.png"]
    assert la.holdings_figure(runs, labels, out) == out / "holdings.png"
    assert [ln.get_label() for ln in saved_figures["holdings.png"].axes[0].get_lines()][:2] == [
        "dgpq (5 evaluation episodes)", "ddpg (5 evaluation episodes)"]
    assert len(asked) == 2
    monkeypatch.setattr(evaluate, "job_folders", lambda path: [path])
    la.holdings_figure(runs, labels, out)
    assert asked[-1] == (Path("ddpg"), 10) and saved_figures["holdings.png"]._suptitle is None   # the defaults


def test_holdings_hold_zero_once_sold_out_and_pad_episodes_that_end_early(tmp_path):
    """DGPQ selling 0, half or all of what is left (3 levels; sigma_tol2 so small that Q̂ is never
    overwritten and every action ties): each seed's holdings fall by its level's share at each trade,
    and are 0 from the trade that sells out to the end of the 8-trade grid."""
    from trl_dgpq.commands import train
    out = tmp_path / "dgpq"
    assert train.main(["--env", "liquidation", "--agent", "dgpq", "--trades", "8", "--action-levels", "3",
                       "--seeds", "0-3", "--episodes", "1", "--set", "sigma_tol2=1e-12", "--out", str(out),
                       "--no-progress"]) == 0
    got = la.holdings(out, episodes=4)
    assert got.shape == (16, 9) and (got[:, 0] == 1).all() and (got[:, -1] == 0).all()
    early = 0
    for row in got:
        ended = False
        for a, b in zip(row[:-1], row[1:]):
            if ended:
                assert b == 0
            else:
                assert b == pytest.approx(a, abs=1e-7) or b == pytest.approx(a / 2, abs=1e-7) or b == 0
                ended = b == 0
        early += int(row[-2] == 0)
    assert early > 0                                   # some seeds sold out before the last trade


# ------------------------------------------------------------------ the claims
def test_the_twap_closed_form_is_ac00s_sums_over_even_trades():
    """E = eps X + gamma X^2 / 2 + (eta~ / tau) N (X / N)^2; V = sigma^2 tau sum_k x_k^2 with x_k = X (1 - k / N)."""
    m = DEFAULT
    X, N = m.shares, m.trades
    E = m.eps * X + m.gamma * X ** 2 / 2 + m.eta_tilde / m.tau * N * (X / N) ** 2
    V = m.sigma2 * m.tau * sum((X * (1 - k / N)) ** 2 for k in range(1, N + 1))
    got = la.twap_closed_form()
    assert got == pytest.approx(dict(cost=(E + m.lam * V) / m.utility(), shortfall=E / m.expected_shortfall()),
                                rel=1e-12)
    assert got["cost"] == pytest.approx(4.307, abs=1e-3) and got["shortfall"] == pytest.approx(0.475, abs=1e-3)
    assert la.market() == DEFAULT


def test_the_claims_measures_by_hand():
    opt = run("ac-optimal", ac_cost=lambda s, e: 1.0 * e + 4 * s, implementation_shortfall=2.0)
    runs = {"liq-ac-optimal": opt}
    got = la.ac_cost_mean("liq-ac-optimal")(runs)               # 1, 2, 3, 4, 5, 6, 7, 8: mean 4.5
    se = np.std(np.arange(1, 9), ddof=1) / math.sqrt(8)
    assert (got.point, got.low, got.high) == pytest.approx((4.5, 4.5 - 1.96 * se, 4.5 + 1.96 * se))
    assert got.statistic == "mean over 8 seed-episodes [95 % CI]"
    # paired: 1 + (ours - the optimum's on the same seed-episode) / scale; pairs the twap run lacks drop out
    twap = run("twap", seeds=(1,), ac_cost=lambda s, e: 5.0 + 2 * e + 4 * s, implementation_shortfall=3.0)
    runs["liq-twap"] = twap
    got = la.paired_mean("liq-twap", "ac_cost", 10.0)(runs)        # 1 + (5 + e) / 10 for e = 1..4: mean 1.75
    assert got.point == pytest.approx(1.75) and got.statistic == "mean over 4 seed-episodes paired with the " \
                                                                 "optimum's [95 % CI]"
    assert la.paired_mean("liq-twap", "implementation_shortfall", 4.0)(runs).point == pytest.approx(1.25)
    elsewhere = run("twap", env={"lam": 1e-5}, path="runs/lam", ac_cost=1.0, implementation_shortfall=1.0)
    for measure in (la.ac_cost_mean("x"), la.paired_mean("x", "ac_cost", 1.0)):
        with pytest.raises(ValueError, match=r"^runs/lam: its market differs from the default one whose closed "
                                             r"forms the claims quote$"):
            measure({"x": elsewhere, "liq-ac-optimal": opt})


def test_the_drift_measures_are_per_seed_noise_free_means():
    """Blocks of 2 after episode 2 over 6 episodes (the defaults' shape, scaled down): seed 0's noise-free
    ratios 1.0 1.0 | 1.1 1.1 | 1.2 1.2, seed 1's all 1.0; its last 2 episodes 1.2 and 1.0, the worst block
    over the best 1.2 / 1.1 and 1.0."""
    r = run("dgpq", episodes=6, noise_free_cost_ratio=lambda s, e: 1.0 if s else 1.0 + 0.1 * ((e - 1) // 2))
    runs = {"d": r}
    last = la.drift_measure("d", "last", block=2, settle=2, last=2)(runs)
    assert last.point == pytest.approx(1.1) and last.statistic == "IQM over 2 seeds [95 % CI]"
    worst = la.drift_measure("d", "worst", block=2, settle=2, last=2)(runs)
    assert worst.point == pytest.approx((1.2 / 1.1 + 1.0) / 2)
    with pytest.raises(ValueError, match="^d ran 6 episodes: too few for blocks after episode 3$"):
        la.drift_measure("d", "last", block=2, settle=3, last=2)(runs)
    assert la.drift_measure("d", "last", block=2, settle=2, last=2)(runs) == last     # settle + 2 blocks: enough
    r.df.loc[r.df.episode == 5, "noise_free_cost_ratio"] = float("nan")
    with pytest.raises(ValueError, match=r"^d: not every weighed episode has the noise-free cost ratio \(a run "
                                         r"from before the column\): run it again$"):
        la.drift_measure("d", "last", block=2, settle=2, last=2)(runs)


DRIFT = [("tuned", "`tuned`"), ("late", "`late`"), ("late-eps1", "`late` with eps1 0.002"), ("once", "`once`"),
         ("steady", "`steady`"), ("flat", "`flat`")]


def test_the_claims_words_rules_and_runs():
    claims = la.declared_claims()
    assert [c.key for c in claims] == ["liquidation/u-star", "liquidation/twap-cost", "liquidation/twap-shortfall"] + [
        f"liquidation/drift/{name}/{kind}" for name, _ in DRIFT for kind in ("last", "worst-block")]
    u, cost, shortfall = claims[:3]
    twap = la.twap_closed_form()
    assert u.statement == f"the optimal schedule's expected ac_cost U* = ${DEFAULT.utility():,.0f} (closed form)"
    assert u.statement == "the optimal schedule's expected ac_cost U* = $704,723 (closed form)"
    assert u.rule == Agrees(DEFAULT.utility(), 1, higher_is_better=False) and u.fmt == "{:,.0f}"
    assert u.needs == ("liq-ac-optimal",) and u.source == "AC00"
    assert u.source_model == ("the AC model's closed-form schedule",)
    assert cost.statement == "TWAP's expected ac_cost is 4.307x U* (closed form)"
    assert cost.rule == Agrees(twap["cost"], 1, higher_is_better=False)
    assert shortfall.statement == "TWAP's expected shortfall is 0.475x the optimum's E* (closed form)"
    assert shortfall.rule == Agrees(twap["shortfall"], 1, higher_is_better=False)
    for c in (cost, shortfall):
        assert c.needs == ("liq-twap", "liq-ac-optimal") and c.fmt == "{:.3f}" and c.source == "AC00"
        assert c.source_model == ()
    for c in claims[:3]:
        assert c.decided_at == ("quick", "full", "report")
    for (name, who), (lastc, worst) in zip(DRIFT, zip(claims[3::2], claims[4::2])):
        for c in (lastc, worst):
            assert c.needs == (f"liq-dgpq-{name}",) and c.source == "this suite" and c.decided_at == ("report",)
        assert lastc.statement == (f"the goal that DGPQ stops drifting: DGPQ {who}'s last 1,000 episodes cost at "
                                   "most 1.10 U* (each seed's noise-free cost ratio)")
        assert lastc.rule == Bound(1.10, higher_is_better=False) and lastc.fmt == "{:.3f}"
        assert worst.statement == (f"the goal that DGPQ stops drifting: after episode 1,000 DGPQ {who}'s worst block "
                                   "of 500 episodes costs at most 1.02x its best (each seed's, noise-free)")
        assert worst.rule == Bound(1.02, higher_is_better=False) and worst.fmt == "{:.4f}"
    # the measures are the claims' own: each read on runs by hand
    opt = run("ac-optimal", ac_cost=lambda s, e: float(e), implementation_shortfall=lambda s, e: 2.0 * e)
    tw = run("twap", ac_cost=lambda s, e: e + DEFAULT.utility(), implementation_shortfall=lambda s, e: 2.0 * e)
    runs = {"liq-ac-optimal": opt, "liq-twap": tw}
    assert u.measure(runs).point == pytest.approx(2.5)
    assert cost.measure(runs).point == pytest.approx(2.0) and shortfall.measure(runs).point == pytest.approx(1.0)
    d = run("dgpq", episodes=2000, seeds=(0,), noise_free_cost_ratio=lambda s, e: 1.0 + (e > 1500) * 0.03)
    got = {c.key.rsplit("/", 1)[1]: c.measure({"liq-dgpq-tuned": d}).point for c in claims[3:5]}
    assert got == {"last": pytest.approx(1.015), "worst-block": pytest.approx(1.03)}


# ------------------------------------------------------------------ REPORT.md's section
def test_the_section_by_hand_with_its_figures_stubbed(tmp_path, monkeypatch):
    """The figures get every run, their names without "liq-", blocks of a fifth of half the shortest
    run; the section is the comparison table, the verdicts, the trades of the two utility-ratio DDPGs
    in their second halves, the seed report's settings, and the figures (holdings only if drawn)."""
    from types import SimpleNamespace
    called = []

    def figures(runs, labels, out, block, last, title):
        called.append((runs, labels, out, block, last, title))
        (out / "comparison.md").write_text("TABLE\n")
    monkeypatch.setattr(la, "figures", figures)
    ours = run("ddpg", episodes=20, ac_cost=1.0, steps=lambda s, e: 60 if e <= 10 else 2 + s)   # 2.5 after 10
    course = run("ddpg", episodes=30, ac_cost=1.0, steps=lambda s, e: 1 if e <= 15 else 10 * (s + 1))  # 15 after 15
    runs = {"liq-ddpg-utility-ratio": ours, "liq-ddpg-course": course}
    judged = [SimpleNamespace(bullet=lambda: "- one"), SimpleNamespace(bullet=lambda: "- two")]
    text = la.reproduce_section(runs, tmp_path, "LABEL", "TITLE", judged)
    assert called == [([ours, course], ["ddpg-utility-ratio", "ddpg-course"], tmp_path / "liquidation", 2, 10,
                       "TITLE")]                                      # half the shortest run, in blocks of a fifth
    assert text == (
        "## Optimal liquidation (seed report 4.4) -- Figures 6-7\n\nLABEL\n\nTABLE\n\n- one\n- two\n"
        "- The seed report's utility-ratio reward pays most for selling everything at once. DDPG on it trades 2.5 "
        "times per episode (of 60) in its second half.\n"
        "- The course's own DDPG (`course` preset: its uniform, never-reset OU noise, its initial weights, critic then "
        "actor) trades 15.0 times per episode in its second half (mean over seed-episodes), ours on the same reward "
        "2.5: the course's agent sells in more trades.\n"
        "- The seed report's DGPQ settings (report-0.01 / report-0.99) never overwrite Q̂ (Section 5's sigma_tol2 is "
        "far below what the GPs reach): every action ties, the agent sells uniformly random fractions, and the two "
        "discounts give the same episodes.\n\n"
        "![cost](liquidation/liquidation_cost.png) ![time](liquidation/liquidation_time.png)\n")
    (tmp_path / "liquidation" / "holdings.png").write_bytes(b"")
    short = {k: run("ddpg", episodes=3, steps=5) for k in runs}
    text = la.reproduce_section(short, tmp_path, "L", "T", [])
    assert called[-1][3:5] == (1, 1)                                      # one episode each: at least 1
    assert text.endswith(" ![holdings](liquidation/holdings.png)\n")
    assert "sells in as many trades." in text                             # 5.0 against 5.0


def test_the_course_sentence_says_more_or_fewer_by_the_second_halves():
    """Second halves: episodes past max // 2 (3-5 of 5; 2-5 would include episode 2's 100 steps)."""
    def two(course, ours):
        c = run("ddpg", episodes=len(course), seeds=(0,), steps=lambda s, e: course[e - 1])
        o = run("ddpg", episodes=len(ours), seeds=(0,), steps=lambda s, e: ours[e - 1])
        return la.course_sentence({"liq-ddpg-course": c, "liq-ddpg-utility-ratio": o})
    assert two([1, 100, 30, 30, 60], [9, 9, 9, 9, 9]).endswith("trades 40.0 times per episode in its second half "
                                                              "(mean over seed-episodes), ours on the same reward 9.0: "
                                                              "the course's agent sells in more trades.")
    assert two([5, 5, 5, 5], [1, 100, 6, 6]).endswith("trades 5.0 times per episode in its second half (mean over "
                                                      "seed-episodes), ours on the same reward 6.0: the course's agent "
                                                      "sells in fewer trades.")
