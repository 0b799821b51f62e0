"""analysis/report.py's parts on small made-up runs, by hand: the budget a report uses, which
runs may be reported on, the profiles figure's data, and the table's cells."""
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from trl_dgpq.analysis import report as rp
from trl_dgpq.analysis.runs import Run
from trl_dgpq.selection import SelectionSeedsError


def run(steps_per_seed, env_steps=None, seeds=None, agent="dgpq", path="runs/r", env="square"):
    """A run whose seed i took ``steps_per_seed[i]`` steps in each of its episodes (3 episodes)."""
    rows = [dict(seed=s, episode=e, steps=n) for s, n in enumerate(steps_per_seed) for e in (1, 2, 3)]
    df = pd.DataFrame(rows)
    df["env_steps"] = df.groupby("seed")["steps"].cumsum()
    seeds = seeds or list(range(len(steps_per_seed)))
    config = {"run": {"env": env, "agent": agent, "preset": "shaped", "seeds": seeds,
                      **({"env_steps": env_steps} if env_steps is not None else {})}, "env": {}, "agent": {}}
    return Run(Path(path), df, config)


# ---------------------------------------------------------------- the budget


def test_the_budget_is_the_runs_common_env_steps():
    assert rp.default_budget([("a", run([5, 7], env_steps=900)), ("b", run([2], env_steps=900))]) == 900


def test_without_a_common_budget_it_is_the_fewest_steps_any_seed_ran():
    # seeds ran 15 and 21 steps, and 6: the fewest is 6
    assert rp.default_budget([("a", run([5, 7])), ("b", run([2]))]) == 6
    assert rp.default_budget([("a", run([5, 7], env_steps=900)), ("b", run([2], env_steps=800))]) == 6
    assert rp.default_budget([("a", run([5, 7], env_steps=900)), ("b", run([2]))]) == 6
    assert rp.default_budget([("a", run([5, 7], env_steps=0))]) == 15
    assert isinstance(rp.default_budget([("a", run([5, 7]))]), int)


# ---------------------------------------------------------------- which runs may be reported


def test_a_run_is_checked_on_its_configs_seeds_and_those_its_rows_hold():
    rp.reportable(run([1, 2], seeds=[0, 1]))                                      # reporting seeds: fine
    with pytest.raises(SelectionSeedsError, match=r"^runs/bad \(dgpq on square, preset 'shaped'\).*1000"):
        rp.reportable(run([1, 2], seeds=[0, 1000], path="runs/bad"))              # the config's seeds
    rows = run([1, 2], seeds=[0, 1], path="runs/rows")
    rows.df.loc[rows.df.seed == 1, "seed"] = 1001
    with pytest.raises(SelectionSeedsError, match=r"^runs/rows \(dgpq on square.*1001"):
        rp.reportable(rows)                                                        # the rows' seeds
    no_seeds = run([1, 2], path="runs/n")
    del no_seeds.config["run"]["seeds"]
    rp.reportable(no_seeds)                                                        # the rows' 0 and 1 stand in


def test_a_run_without_a_config_is_not_checked():
    rp.reportable(Run(Path("runs/x"), pd.DataFrame({"seed": [5000]}), None))


# ---------------------------------------------------------------- the profiles figure


def drawn_profiles(monkeypatch, saved_figures, tmp_path, scores, curves=None):
    """profile_figure on ``scores`` (given ``curves``, with rliable's profiles stubbed): the axes it drew."""
    if curves is not None:
        monkeypatch.setattr(rp, "profiles", lambda s, taus: curves(s, taus))
    assert rp.profile_figure(scores, tmp_path) == tmp_path / "profiles.png"
    return saved_figures["profiles.png"].axes[0]


SCORES = {"dgpq": {"t1": np.array([0.0, 1.0, 2.0]), "t2": np.array([5.0, 5.0, 6.0])},
          "dqn": {"t1": np.array([1.0, 1.0, 1.0]), "t2": np.array([4.0, 4.0, 4.0])}}


def test_the_profiles_figure_draws_each_agents_fraction_above_each_tau(monkeypatch, saved_figures, tmp_path):
    ax = drawn_profiles(monkeypatch, saved_figures, tmp_path, SCORES)
    lines = {line.get_label(): line for line in ax.get_lines()}
    assert set(lines) == {"dgpq (2 tasks x 3 seeds)", "dqn (2 tasks x 3 seeds)"}
    taus = np.linspace(0.0, 1.0, 51)
    # normalised: t1 over [0, 2], t2 over [4, 6]: dgpq's scores 0, .5, 1 and .5, .5, 1; dqn's .5 x 3 and 0 x 3
    dgpq = np.array([0.0, 0.5, 1.0, 0.5, 0.5, 1.0])
    dqn = np.array([0.5, 0.5, 0.5, 0.0, 0.0, 0.0])
    for name, s in (("dgpq (2 tasks x 3 seeds)", dgpq), ("dqn (2 tasks x 3 seeds)", dqn)):
        assert np.array_equal(lines[name].get_xdata(), taus)
        assert np.allclose(lines[name].get_ydata(), [(s > tau).mean() for tau in taus])
    assert ax.get_xlabel() == "normalised score at budget tau (each task: 0 = worst run's, 1 = best run's)"
    assert ax.get_ylabel() == "fraction of runs with score > tau"
    assert ax.get_title() == "performance profiles (rliable; band: 95 % bootstrap CI)"
    assert [t.get_text() for t in ax.get_legend().get_texts()] == list(lines)


def test_each_agents_band_is_its_interval_in_its_curves_colour(monkeypatch, saved_figures, tmp_path):
    """rliable's profiles stubbed: a curve of 0.5 with the band [0.2, 0.9] for dgpq, 0.1 in [0, 0.3] for dqn."""
    import matplotlib.colors

    def curves(scores, taus):
        n = len(taus)
        assert n == 51 and taus[0] == 0.0 and taus[-1] == 1.0
        return ({"dgpq": np.full(n, 0.5), "dqn": np.full(n, 0.1)},
                {"dgpq": (np.full(n, 0.2), np.full(n, 0.9)), "dqn": (np.full(n, 0.0), np.full(n, 0.3))})
    ax = drawn_profiles(monkeypatch, saved_figures, tmp_path, SCORES, curves)
    lines = ax.get_lines()
    assert [set(line.get_ydata()) for line in lines] == [{0.5}, {0.1}]
    for band, line, (lo, hi) in zip(ax.collections, lines, [(0.2, 0.9), (0.0, 0.3)]):
        xy = band.get_paths()[0].vertices
        assert set(np.round(xy[:, 1], 12)) == {lo, hi} and xy[:, 0].min() == 0.0 and xy[:, 0].max() == 1.0
        assert tuple(band.get_facecolor()[0][:3]) == matplotlib.colors.to_rgb(line.get_color())


def test_no_profiles_for_one_task_or_no_agent_on_every_task(tmp_path):
    assert rp.profile_figure({"dgpq": {"t1": np.ones(3)}, "dqn": {"t1": np.ones(3)}}, tmp_path) is None
    assert rp.profile_figure({"dgpq": {"t1": np.ones(3)}, "dqn": {"t2": np.ones(3)}}, tmp_path) is None
    assert not (tmp_path / "profiles.png").exists()


# ---------------------------------------------------------------- the table's cells and groups


def test_the_kernel_fits_cell_is_each_seeds_count_or_none_trained_or_not_a_dgpq_column():
    fitted = run([1, 1])
    fitted.df["kernel_fits"] = [0, 1, 2, 1, 3, 4]         # a counter: seed 0 made 2, seed 1 made 4
    assert rp.kernel_fits_cell(fitted) == "3.0"
    assert rp.kernel_fits_cell(run([1, 1])) == "0"                               # DGPQ with RBF trains none
    assert rp.kernel_fits_cell(run([1, 1], agent="dqn")) == "–"


def test_a_task_is_the_env_settings_less_those_of_the_agents_side_for_the_runs_env_id():
    from types import SimpleNamespace
    r = run([1], env="gym:CartPole-v1")
    r.config["env"] = {"b": 2, "a": 1, "obs_map": "unit"}
    asked = []
    r.__dict__["domain"] = SimpleNamespace(agent_side_settings=lambda env_id: asked.append(env_id) or ("obs_map",))
    assert rp.task_settings(r) == {"b": 2, "a": 1} and asked == ["CartPole-v1"]
    other = run([1], env="gym:CartPole-v1")
    other.config["env"] = {"a": 1, "b": 2, "obs_map": "raw"}
    other.__dict__["domain"] = r.domain
    assert rp.group_key(r) == rp.group_key(other) == ("gym:CartPole-v1", '{"a": 1, "b": 2}')   # keys sorted


def square_run(steps, agent, path):
    """Two seeds of 12 episodes of ``steps`` steps each, 0.1 s of wall time a row."""
    df = pd.DataFrame([dict(seed=s, episode=e, steps=steps, terminated=True, wall_s=0.1, cpu_s=0.1)
                       for s in (0, 1) for e in range(1, 13)])
    df["env_steps"] = df.groupby("seed")["steps"].cumsum()
    config = {"run": {"env": "square", "agent": agent, "preset": "shaped", "seeds": [0, 1], "episodes": 12},
              "env": {}, "agent": {}}
    return Run(Path(path), df, config)


def test_the_report_of_two_runs_by_hand(tmp_path):
    """DGPQ at 20 steps an episode meets the square's threshold (25 over 10 episodes) at its 10th, 200
    steps; DQN at 40 never does. The budget is the fewest steps a seed ran, DGPQ's 240; within it DQN
    ran 6 episodes. Every seed alike: each IQM's interval is its point, each P(improvement) 1."""
    runs = [square_run(20, "dgpq", "runs/a"), square_run(40, "dqn", "runs/b")]
    checked = []
    out = tmp_path / "x" / "y"
    for _ in range(2):                                     # a second report into the same folder
        written, text = rp.report(runs, None, out, check=checked.append)
    assert checked == runs * 2
    assert text == (out / "compare.md").read_text()
    assert text.split("\n") == [
        "# Environment steps to a threshold, and performance at a budget", "",
        "## square", "",
        "Budget: 240 environment steps per seed. Threshold: mean steps per episode <= 25 over 10 episodes. At "
        "budget: steps per episode, mean of each seed's last 10 episodes within the budget; median [IQR] over "
        "seeds; IQM [95 % CI] over seeds (rliable).", "",
        "| run | seeds | steps to threshold (median) | steps to threshold, IQM [95 % CI] | at budget | at budget, "
        "IQM [95 % CI] | kernel fits / seed | ms / seed-step |",
        "|---|---|---|---|---|---|---|---|",
        "| dgpq shaped | 2 | 200 (2/2 seeds met it) | 200 [200, 200] | 20 [20, 20] | 20 [20, 20] | 0 | 5.00 |",
        "| dqn shaped | 2 | never (0/2 seeds met it) | 240 [240, 240] | 40 [40, 40] | 40 [40, 40] | – | 2.50 |",
        "",
        "- P(dgpq shaped improves on dqn shaped), 95 % CI: steps to threshold 1.00 [1.00, 1.00]; at budget 1.00 "
        "[1.00, 1.00].",
        ""]
    assert [p.name for p in written] == ["compare-square.png", "compare.md", "results.csv"]
    lines = rp.report(runs, ["A", "B"], out, budget=120, window=3)[1].split("\n")
    # within 120 env steps: DGPQ's 6 episodes, DQN's 3; the last 3 of each
    assert lines[4] == ("Budget: 120 environment steps per seed. Threshold: mean steps per episode <= 25 over 10 "
                        "episodes. At budget: steps per episode, mean of each seed's last 3 episodes within the "
                        "budget; median [IQR] over seeds; IQM [95 % CI] over seeds (rliable).")
    assert lines[8:10] == [
        "| A | 2 | never (0/2 seeds met it) | 120 [120, 120] | 20 [20, 20] | 20 [20, 20] | 0 | 5.00 |",
        "| B | 2 | never (0/2 seeds met it) | 120 [120, 120] | 40 [40, 40] | 40 [40, 40] | – | 2.50 |"]


def test_a_run_the_check_refuses_stops_the_report_before_anything_is_written(tmp_path):
    def refuse(run):
        raise ValueError(f"{run.path}: no")
    with pytest.raises(ValueError, match="runs/a: no"):
        rp.report([square_run(20, "dgpq", "runs/a")], None, tmp_path / "out", check=refuse)
    assert not (tmp_path / "out").exists()


def test_the_table_says_when_nothing_is_within_the_budget_and_iqm_of_nothing_is_a_dash():
    assert rp.fmt_band(pd.Series([np.nan, np.nan])) == "– (2 seeds: no episode within the budget)"
    assert rp.fmt_iqm(np.array([np.nan, np.nan])) == "–"
    assert rp.fmt_iqm(np.array([2.0, 2.0])) == "2 [2, 2]"
    assert rp.fmt_iqm(np.array([123456.0, 123456.0])) == "1.235e+05 [1.235e+05, 1.235e+05]"   # 4 digits


def test_a_group_is_named_by_the_settings_it_differs_in_from_its_envs_other_groups():
    assert rp.group_name("liquidation", {"a": 1, "b": 2, "c": 3}, [{"a": 1, "b": 5, "c": 4}]) == (
        "liquidation (b=2, c=3)")
    assert rp.group_name("liquidation", {"a": 1}, [{"a": 1}]) == "liquidation"


def test_the_budget_given_bounds_the_threshold_and_the_at_budget_window(tmp_path):
    """Episodes 1-6 of 30 steps, 7-12 of 10: over 10 episodes the mean first meets 25 at episode 10
    (22 steps, 220 env steps); within a budget of 120 env steps a seed ran 4 episodes of 30."""
    r = square_run(30, "dgpq", "runs/a")
    r.df["steps"] = [30] * 6 + [10] * 6 + [30] * 6 + [10] * 6
    r.df["env_steps"] = r.df.groupby("seed")["steps"].cumsum()
    text = rp.report([r], None, tmp_path)[1]
    assert "| dgpq shaped | 2 | 220 (2/2 seeds met it) | 220 [220, 220] | 18 [18, 18] | 18 [18, 18] |" in text
    text = rp.report([r], None, tmp_path, budget=120)[1]
    assert "| dgpq shaped | 2 | never (0/2 seeds met it) | 120 [120, 120] | 30 [30, 30] | 30 [30, 30] |" in text


def test_the_comparison_figure_draws_each_runs_median_and_iqr_against_env_steps_and_the_threshold(saved_figures,
                                                                                                  tmp_path):
    import matplotlib.colors
    runs = [square_run(20, "dgpq", "runs/a"), square_run(40, "dqn", "runs/b")]
    rp.report(runs, None, tmp_path)
    ax = saved_figures["compare-square.png"].axes[0]
    grid = np.linspace(0, 240, 200)[1:]
    lines = {line.get_label(): line for line in ax.get_lines()}
    assert list(lines) == ["dgpq shaped (2 seeds)", "dqn shaped (2 seeds)", "threshold"]
    for label, steps in (("dgpq shaped (2 seeds)", 20), ("dqn shaped (2 seeds)", 40)):
        x, y = lines[label].get_xdata(), lines[label].get_ydata()
        assert np.array_equal(x, grid)
        # each seed's mean of its last 10 episodes as it stood at each step: its steps once it ended one
        assert np.array_equal(np.isnan(y), grid < steps) and set(y[~np.isnan(y)]) == {steps}
    assert set(lines["threshold"].get_ydata()) == {25}
    for band, (label, steps) in zip(ax.collections, [("dgpq shaped (2 seeds)", 20), ("dqn shaped (2 seeds)", 40)]):
        assert tuple(band.get_facecolor()[0][:3]) == matplotlib.colors.to_rgb(lines[label].get_color())
        xy = band.get_paths()[0].vertices
        assert xy[:, 0].max() == 240 and set(xy[:, 1]) == {steps}       # the IQR of equal seeds: their value
    assert ax.get_xlabel() == "environment steps per seed"
    assert ax.get_ylabel() == "steps per episode (mean of last 10)"
    assert ax.get_title() == "square: median and IQR over seeds"
    assert [t.get_text() for t in ax.get_legend().get_texts()] == list(lines)


def test_a_domain_without_a_threshold_says_so_and_leaves_those_cells_empty(saved_figures, tmp_path):
    df = pd.DataFrame([dict(seed=s, episode=e, steps=10, cost_ratio=1.5, wall_s=0.1) for s in (0, 1)
                       for e in (1, 2, 3)])
    df["env_steps"] = df.groupby("seed")["steps"].cumsum()
    config = {"run": {"env": "liquidation", "agent": "twap", "preset": "flat", "seeds": [0, 1], "episodes": 3},
              "env": {}, "agent": {}}
    text = rp.report([Run(Path("runs/l"), df, config)], None, tmp_path)[1]
    assert "Threshold: none defined. At budget:" in text
    assert "| twap flat | 2 | – | – | 1.5 [1.5, 1.5] | 1.5 [1.5, 1.5] | – | 10.00 |" in text
    lines = saved_figures["compare-liquidation.png"].axes[0].get_lines()
    assert [line.get_label() for line in lines] == ["twap flat (2 seeds)"]


def test_runs_of_two_tasks_get_a_table_each_named_by_what_differs_and_the_profiles_under_them(saved_figures,
                                                                                               tmp_path):
    runs = []
    for noise, path in ((0.1, "runs/a"), (0.2, "runs/b")):
        for agent, steps in (("dgpq", 20), ("dqn", 40)):
            r = square_run(steps, agent, f"{path}-{agent}")
            r.config["env"] = {"noise": noise, "goal_radius": 0.15}
            runs.append(r)
    text = rp.report(runs, None, tmp_path)[1]
    headings = [line for line in text.split("\n") if line.startswith("## ")]
    assert headings == ["## square (noise=0.1)", "## square (noise=0.2)"]
    assert sorted(saved_figures) == ["compare-square-noise-0.1.png", "compare-square-noise-0.2.png", "profiles.png"]
    assert text.endswith("\n![profiles](profiles.png)\n")
    table = pd.read_csv(tmp_path / "results.csv")
    assert list(table.iloc[:, 0]) == ["dgpq shaped", "dqn shaped"] * 2
