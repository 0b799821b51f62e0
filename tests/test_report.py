"""scripts/report.py (trl_dgpq.analysis.report): steps to threshold and performance at a budget, by hand."""
import json

import pandas as pd
import pytest

from trl_dgpq.analysis import at_budget, kernel_fits_per_seed, load_run, steps_to_threshold
from trl_dgpq.analysis.report import fmt_band, fmt_steps, group_key, report
from trl_dgpq.commands.report import main
from trl_dgpq.envs import domain

CARTPOLE = domain("gym:CartPole-v1").threshold("CartPole-v1")


def fake_run(folder, env, seeds_steps, returns=None, terminated=None, env_cfg=None, agent="dqn"):
    """A run folder with the given per-seed episode lengths (returns default to the lengths)."""
    folder.mkdir(parents=True)
    rows = []
    for seed, steps in seeds_steps.items():
        for i, s in enumerate(steps):
            rows.append(dict(seed=seed, episode=i + 1, steps=s,
                             **{"return": (returns or {}).get(seed, steps)[i]},
                             terminated=(terminated or {}).get(seed, [False] * len(steps))[i],
                             wall_s=s * 1e-3, cpu_s=0.0, us_per_step=1e3))
    pd.DataFrame(rows).to_csv(folder / "episodes.csv", index=False)
    (folder / "config.json").write_text(json.dumps({"run": {"env": env, "agent": agent, "preset": "p"},
                                                    "env": env_cfg or {}, "agent": {}}))
    return folder


def test_steps_to_threshold_and_budget_by_hand(tmp_path):
    """CartPole, window 10: 10 episodes of 100, then of 300: the mean of the last 10 first reaches
    195 after 5 of 300 (200), at 10 x 100 + 5 x 300 = 2,500 steps. At a budget of 1,900 the last
    10 episodes within it are 7 x 100 + 3 x 300: mean 160."""
    steps = [100] * 10 + [300] * 10
    # seed 2 starts high: only a full window counts, first met at episode 10 (5 x 300 + 5 x 100 = 2,000)
    run = fake_run(tmp_path / "a", "gym:CartPole-v1", {0: steps, 1: [20] * 100, 2: [300] * 5 + [100] * 20})
    df = load_run(run).df
    to = steps_to_threshold(df, CARTPOLE)
    assert to[0] == 2500 and pd.isna(to[1]) and to[2] == 2000
    # budget 1,900 = the end of episode 13 exactly: it counts
    assert at_budget(df, "return", 1900, 10)[0] == pytest.approx(160)
    assert fmt_steps(to) == "2,500 (2/3 seeds met it)"
    assert fmt_steps(to[[0, 1]]) == "never (1/2 seeds met it)"


def test_mountaincar_flag_and_groups(tmp_path):
    """MountainCar's threshold is one episode at the flag: seed 0 at 200 + 200 + 150 = 550 steps,
    seed 2 at 120, seed 1 never: median 550 (within the budget of 600). Square runs with other env settings get their own
    section and figure, named by what differs."""
    car = fake_run(tmp_path / "car", "gym:MountainCar-v0", {0: [200, 200, 150], 1: [200] * 3, 2: [120, 200, 200]},
                   returns={s: [-200] * 3 for s in range(3)},
                   terminated={0: [False, False, True], 1: [False] * 3, 2: [True, False, False]})
    quiet = fake_run(tmp_path / "quiet", "square", {0: [40] * 30}, env_cfg={"reward_noise": 0.0, "max_steps": 200})
    noisy = fake_run(tmp_path / "noisy", "square", {0: [20] * 30}, env_cfg={"reward_noise": 0.1, "max_steps": 200},
                     agent="dgpq")
    written, text = report([car, quiet, noisy], ["dqn car", "dqn quiet", "dgpq noisy"], tmp_path / "out",
                                  budget=600)
    # IQM of 3 seeds trims nothing: (550 + 600 (never: the budget) + 120) / 3
    assert "| dqn car | 3 | 550 (2/3 seeds met it) | 423 [" in text
    assert "## square (reward_noise=0.0)" in text and "## square (reward_noise=0.1)" in text
    assert "| dgpq noisy | 1 | 200 (1/1 seeds met it) | 200 [200, 200] | 20 [20, 20] | 20 [20, 20] |" in text
    assert "| dqn quiet | 1 | never (0/1 seeds met it) | 600 [600, 600] | 40 [40, 40] | 40 [40, 40] |" in text
    assert sorted(p.name for p in written) == ["compare-gym-MountainCar-v0.png", "compare-square-reward_noise-0.0.png",
                                               "compare-square-reward_noise-0.1.png", "compare.md", "results.csv"]
    assert all(p.stat().st_size > 0 for p in written)


def test_probability_that_dgpq_improves_on_dqn_by_hand(tmp_path):
    """Square (threshold: mean steps <= 25 over 10 episodes), budget 240 (the fewest any seed ran).
    Steps to threshold: DGPQ 200, 200; DQN never (counted 240), 200 -> of the 4 pairs DGPQ wins 2 and
    ties 2: P = (1 + 1 + 0.5 + 0.5) / 4. At budget (fewer steps better): DGPQ 20, 20; DQN 30, 20: the same."""
    dgpq = fake_run(tmp_path / "g", "square", {0: [20] * 12, 1: [20] * 12}, agent="dgpq")
    dqn = fake_run(tmp_path / "q", "square", {0: [30] * 12, 1: [20] * 12})
    _, text = report([dgpq, dqn], ["dgpq", "dqn"], tmp_path / "out")
    assert "- P(dgpq improves on dqn), 95 % CI: steps to threshold 0.75 [" in text
    assert "; at budget 0.75 [" in text
    _, text = report([dqn, dgpq], ["dqn", "dgpq"], tmp_path / "out2")
    assert "P(dgpq improves on dqn)" in text and "P(dqn improves" not in text  # DGPQ against DQN only


def test_profiles_over_tasks_are_drawn(tmp_path):
    runs = [fake_run(tmp_path / f"{a}{t}", "square", {0: [20 + i] * 12, 1: [30] * 12}, agent=a,
                     env_cfg={"max_steps": 100 + t}) for i, a in enumerate(("dgpq", "dqn")) for t in (0, 1)]
    written, text = report(runs, ["g0", "g1", "q0", "q1"], tmp_path / "out")
    assert (tmp_path / "out" / "profiles.png") in written and "![profiles](profiles.png)" in text


def test_runs_differing_only_on_the_agents_side_share_a_table(tmp_path):
    """Liquidation on 21 sale levels (DGPQ) and on none (the AC optimum) is one task; another
    reward is another; file names carry no '='."""
    runs = [fake_run(tmp_path / "d", "liquidation", {0: [60] * 12}, agent="dgpq", env_cfg={"action_levels": 21}),
            fake_run(tmp_path / "o", "liquidation", {0: [60] * 12}, agent="ac-optimal", env_cfg={"action_levels": 0}),
            fake_run(tmp_path / "u", "liquidation", {0: [60] * 12}, agent="ddpg",
                     env_cfg={"action_levels": 0, "reward": "utility-ratio"})]
    for run in runs:  # the measure's column
        df = pd.read_csv(run / "episodes.csv").assign(cost_ratio=1.0)
        df.to_csv(run / "episodes.csv", index=False)
    written, text = report(runs, ["dgpq", "opt", "ddpg"], tmp_path / "out")
    sections = {part.splitlines()[0]: part for part in text.split("\n## ")[1:]}
    assert set(sections) == {"liquidation", "liquidation (reward=utility-ratio)"}
    one = next(part for name, part in sections.items() if "utility" not in name)
    assert "| dgpq |" in one and "| opt |" in one and "| ddpg |" not in one and "action_levels" not in text
    assert not any("=" in p.name for p in written)
    a, b = (group_key(load_run(r)) for r in runs[:2])
    assert a == b != group_key(load_run(runs[2]))


def test_bad_input_is_one_line(tmp_path, capsys):
    assert main([str(tmp_path)]) == 2
    assert "not a run folder" in capsys.readouterr().err


def test_a_seed_with_nothing_within_the_budget_still_counts(tmp_path):
    run = fake_run(tmp_path / "a", "gym:CartPole-v1", {0: [300] * 12, 1: [600] * 12, 2: [300] * 12})
    df = load_run(run).df
    to = steps_to_threshold(df, CARTPOLE, budget=3000)
    assert to.tolist()[0] == 3000 and to.isna().tolist() == [False, True, False]
    assert fmt_band(at_budget(df, "return", 500, 10)) == "300 [300, 300] (1 seeds: no episode within the budget)"


def test_kernel_fits_per_seed_is_each_seeds_count_averaged(tmp_path):
    """kernel_fits is a running count per seed: seed 0 ends at 3, seed 1 at 4, so 3.5 per seed
    (not the sum of the rows, nor of the seeds)."""
    run = fake_run(tmp_path / "k", "square", {0: [30, 20, 20], 1: [25, 25, 20]}, agent="dgpq",
                   env_cfg={"max_steps": 200})
    df = pd.read_csv(run / "episodes.csv")
    df["kernel_fits"] = [0, 1, 3, 2, 2, 4]
    df.to_csv(run / "episodes.csv", index=False)
    assert kernel_fits_per_seed(load_run(run).df) == 3.5
    _, text = report([run], ["m"], tmp_path / "out")
    assert "| m | 2 | " in text and "| 3.5 |" in text


def test_plot_draws_a_folder_without_its_config(tmp_path):
    """An episodes.csv alone (copied out of a run folder) still gets the generic figures."""
    from trl_dgpq.commands import plot
    run = fake_run(tmp_path / "bare", "square", {0: [30, 20], 1: [25, 25]})
    (run / "config.json").unlink()
    assert plot.main([str(run)]) == 0
    assert (run / "steps_per_episode.png").is_file() and (run / "time_per_step.png").is_file()


def test_time_per_step_is_the_wall_time_the_console_prints_and_legends_name_agents(tmp_path):
    from trl_dgpq.analysis.figures import FIGURES
    from trl_dgpq.commands.plot import default_labels
    df = pd.DataFrame({"steps": [4, 10], "wall_s": [0.002, 0.01], "cpu_s": [0.004, 0.02]})
    assert list(FIGURES["time_per_step.png"][1](df)) == pytest.approx([0.5, 1.0])   # ms per step, from wall_s
    a = fake_run(tmp_path / "square-dgpq-p-20261123-101010", "square", {0: [3]}, agent="dgpq")
    b = fake_run(tmp_path / "square-dqn-p-20261123-101011", "square", {0: [3]})
    c = fake_run(tmp_path / "again", "square", {0: [3]})
    (c / "config.json").unlink()
    assert default_labels([load_run(a), load_run(b), load_run(c, need_config=False)]) == ["dgpq p", "dqn p", "again"]
    assert default_labels([load_run(b), load_run(b)]) == [b.name, b.name]  # the same label twice: the folders'


def test_runs_sharing_agent_and_preset_are_told_apart_by_folder(tmp_path):
    """Two DQN runs of one task (the compare sweep's 20,000-step and zoo-budget runs) must not both
    read "dqn p" in the table."""
    a = fake_run(tmp_path / "cartpole-dqn", "square", {0: [40] * 5})
    b = fake_run(tmp_path / "cartpole-dqn-zoo", "square", {0: [30] * 5})
    c = fake_run(tmp_path / "cartpole-dgpq", "square", {0: [20] * 5}, agent="dgpq")
    d = fake_run(tmp_path / "noisy-dgpq", "square", {0: [20] * 5}, agent="dgpq", env_cfg={"reward_noise": 0.1})
    _, text = report([a, b, c, d], None, tmp_path / "out", budget=200)
    assert "| dqn p (cartpole-dqn) | 1 |" in text and "| dqn p (cartpole-dqn-zoo) | 1 |" in text
    assert text.count("| dgpq p | 1 |") == 2             # one per task: nothing to tell apart


def test_at_budget_direction_is_the_measures_not_the_thresholds(tmp_path):
    """Push: the threshold is success (more is better), the measure steps per episode (fewer is
    better). DGPQ at 10 steps per episode against DQN at 30 improves on it with probability 1."""
    dgpq = fake_run(tmp_path / "g", "push", {s: [10] * 12 for s in range(3)}, agent="dgpq")
    dqn = fake_run(tmp_path / "q", "push", {s: [30] * 12 for s in range(3)})
    for run in (dgpq, dqn):  # push's own column for its threshold
        pd.read_csv(run / "episodes.csv").assign(success=True).to_csv(run / "episodes.csv", index=False)
    _, text = report([dgpq, dqn], None, tmp_path / "out", budget=400)
    assert "at budget 1.00 [1.00, 1.00]" in text, text


@pytest.fixture
def scored(monkeypatch):
    """The report with rliable's bootstraps left out (seconds each, and not what these tests are
    about): what each comparison is given is recorded instead, as {"improvement": [(x, y), ...],
    "profiles": [task_scores]}."""
    from trl_dgpq.analysis import report as module
    seen = {"improvement": [], "profiles": []}

    def improvement(x, y):
        seen["improvement"].append((list(x), list(y)))
        return 0.5, 0.0, 1.0
    monkeypatch.setattr(module, "iqm", lambda values: (0.0, 0.0, 0.0))
    monkeypatch.setattr(module, "probability_of_improvement", improvement)
    monkeypatch.setattr(module, "profile_figure", lambda task_scores, out: seen["profiles"].append(task_scores))
    return seen


def test_profiles_take_an_agents_first_run_of_a_task(tmp_path, scored):
    """Two DQN runs of one square task, 30 then 50 steps per episode, and a DGPQ run: the profiles
    get the first DQN run's at-budget scores (steps per episode, fewer better: -30 for each seed),
    as documented, not the second's (-50)."""
    runs = [fake_run(tmp_path / "q1", "square", {0: [30] * 12, 1: [30] * 12}),
            fake_run(tmp_path / "q2", "square", {0: [50] * 12, 1: [50] * 12}),
            fake_run(tmp_path / "g", "square", {0: [20] * 12, 1: [20] * 12}, agent="dgpq")]
    report(runs, ["q1", "q2", "g"], tmp_path / "out", budget=300)
    (task_scores,) = scored["profiles"]
    assert {a: {t: list(s) for t, s in per.items()} for a, per in task_scores.items()} == {
        "dqn": {"square": [-30.0, -30.0]}, "dgpq": {"square": [-20.0, -20.0]}}


@pytest.mark.parametrize("env, returns", [("f16", (-40.0, -130.0)), ("gym:CartPole-v1", (150.0, 20.0))])
def test_a_domain_declaring_no_direction_counts_more_as_better(tmp_path, scored, env, returns):
    """The F-16 and gym declare no direction for their measure, the return: the documented default,
    more is better, so DGPQ's and DQN's returns are compared as they are (not negated)."""
    from trl_dgpq.envs import domain, split_name
    assert not hasattr(domain(env).analysis(), "MEASURE_LOWER_IS_BETTER")
    assert domain(env).measure(split_name(env)[1])[0] == "return"
    dgpq, dqn = (fake_run(tmp_path / agent, env, {s: [10] * 12 for s in range(3)}, agent=agent,
                          returns={s: [r] * 12 for s in range(3)}) for agent, r in zip(("dgpq", "dqn"), returns))
    report([dgpq, dqn], None, tmp_path / "out", budget=120)
    assert scored["improvement"][-1] == ([returns[0]] * 3, [returns[1]] * 3)   # at budget: the last comparison


def test_a_run_without_its_domains_measure_column_is_named_in_one_line(tmp_path):
    """A liquidation run from before the env recorded cost_ratio: report and the study's
    objective name the run and the column, not a pandas KeyError."""
    from trl_dgpq.analysis.objective import objective
    folder = fake_run(tmp_path / "old", "liquidation", {0: [60] * 12}, agent="dgpq")
    df = pd.read_csv(folder / "episodes.csv").assign(ac_cost=1.0)
    df.drop(columns=[c for c in ("cost_ratio",) if c in df]).to_csv(folder / "episodes.csv", index=False)
    with pytest.raises(ValueError, match=r"old: episodes.csv has no 'cost_ratio' column.*run it again"):
        report([folder], ["old"], tmp_path / "out")
    with pytest.raises(ValueError, match="no 'cost_ratio' column"):
        objective("liquidation").value(load_run(folder))
