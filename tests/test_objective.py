"""What a study optimises (analysis/objective.py), on a four-seed run small enough to score by hand.

Seeds 0-3, four episodes each; ``x`` the measure, ``steps`` each episode's length:

    seed  steps           env_steps        x
    0     10, 8, 6, 4     10, 18, 24, 28   1, 2, 3, 4
    1     5, 5, 5, 5      5, 10, 15, 20    4, 3, 2, 1
    2     20, 20, 2, 2    20, 40, 42, 44   10, 0, 0, 10
    3     1, 30, 1, 1     1, 31, 32, 33    5, 5, 5, 5

The IQM of four values is the mean of the middle two (rliable's, as the report's)."""
import math

import pandas as pd
import pytest

from trl_dgpq.analysis.objective import Objective, at_budget_objective, covers, objective, stage, worst_objective
from trl_dgpq.analysis.runs import Run
from trl_dgpq.analysis.summary import Threshold
from trl_dgpq.envs import domain

STEPS = {0: [10, 8, 6, 4], 1: [5, 5, 5, 5], 2: [20, 20, 2, 2], 3: [1, 30, 1, 1]}
X = {0: [1, 2, 3, 4], 1: [4, 3, 2, 1], 2: [10, 0, 0, 10], 3: [5, 5, 5, 5]}


def run(episodes=4, env_steps=25, path="somewhere"):
    rows = [dict(seed=s, episode=e + 1, steps=STEPS[s][e], x=float(X[s][e])) for s in (3, 1, 0, 2) for e in range(4)]
    df = pd.DataFrame(rows).sort_values(["seed", "episode"]).reset_index(drop=True)
    df["env_steps"] = df.groupby("seed")["steps"].cumsum()
    return Run(path, df, {"run": {"env": "square", "episodes": episodes, "env_steps": env_steps, "seeds": [0, 1, 2, 3]},
                          "agent": {}})


def at(window=2, direction="minimize", column="x"):
    return Objective("x at budget", "text", direction, None, column, window)


def test_the_measure_at_the_budget_is_each_seeds_last_window_within_it():
    # budget 25: seed 0 ends episodes 1-3 within it, seed 1 all four, seeds 2 and 3 their first only
    assert at().per_seed(run()).tolist() == [2.5, 1.5, 10.0, 5.0]
    assert at().value(run()) == 3.75                                     # (2.5 + 5) / 2
    assert at(window=1).per_seed(run()).tolist() == [3.0, 1.0, 10.0, 5.0]
    # no budget in steps: the fewest steps any seed ran (seed 1's 20)
    assert at().per_seed(run(env_steps=0)).tolist() == [1.5, 1.5, 10.0, 5.0]
    assert at(column="x").per_seed(run()).index.tolist() == [0, 1, 2, 3]
    with pytest.raises(ValueError, match="episodes.csv has no 'cost' column"):
        at(column="cost").per_seed(run())


def test_steps_to_a_threshold_count_a_seed_that_never_met_it_within_the_budget_as_the_budget():
    # mean x over 2 episodes <= 2: seed 0 at episode 2 (18 steps), seed 1 at 4 (20), seed 2 at 3 (42,
    # past the budget of 25), seed 3 never
    steps = Objective("steps to threshold", "t", "minimize", Threshold("x", "<=", 2.0, 2, "t"), "x")
    assert steps.per_seed(run()).tolist() == [18.0, 20.0, 25.0, 25.0]
    assert steps.value(run()) == 22.5
    assert steps.per_seed(run(env_steps=50)).tolist() == [18.0, 20.0, 42.0, 50.0]


def test_the_worst_of_the_stages_ends_is_the_highest_when_minimised_and_the_lowest_when_maximised():
    ends = ((2, 0), (4, 0))    # each seed's episodes 1-2, then 3-4
    worst = Objective("w", "t", "minimize", None, "x", 2, ends)
    assert worst.per_seed(run(env_steps=0)).tolist() == [3.5, 3.5, 5.0, 5.0]
    best = Objective("w", "t", "maximize", None, "x", 2, ends)
    assert best.per_seed(run(env_steps=0)).tolist() == [1.5, 1.5, 5.0, 5.0]
    # a run staged to its third episode reaches the first end only; one of a single episode none
    assert worst.per_seed(run(episodes=3, env_steps=0)).tolist() == [1.5, 3.5, 5.0, 5.0]
    none = worst.per_seed(run(episodes=1, env_steps=0))
    assert none.index.tolist() == [0, 1, 2, 3] and none.isna().all() and none.dtype == float
    # a seed with no episode before an end is NaN there, not left out (seed 2 staged to one episode)
    short = stage(run(), dict(episodes=4, env_steps=20))
    lone = Objective("w", "t", "minimize", None, "x", 1, ((2, 0),)).per_seed(short)
    assert lone.index.tolist() == [0, 1, 2, 3] and lone.isna().tolist() == [False, False, True, False]
    assert math.isnan(worst.value(run(episodes=1, env_steps=0)))
    wide = Objective("w", "t", "minimize", None, "x", 3, ((3, 0),))       # episodes 1-3
    assert wide.per_seed(run(env_steps=0)).tolist() == [2.0, 3.0, 10 / 3, 5.0]
    # ends in env steps: the measure at each budget, as at_budget scores it
    by_steps = Objective("w", "t", "minimize", None, "x", 2, ((4, 20), (4, 25)))
    assert by_steps.per_seed(run(env_steps=25)).tolist() == [2.5, 1.5, 10.0, 5.0]
    assert by_steps.per_seed(run(env_steps=20)).tolist() == [1.5, 1.5, 10.0, 5.0]    # 25 not reached
    with pytest.raises(ValueError, match="no 'cost' column"):
        Objective("w", "t", "minimize", None, "cost", 2, ends).per_seed(run())


def test_a_run_covers_lengths_up_to_its_own():
    config = run().config
    assert covers(config, dict(episodes=4, env_steps=25)) and covers(config, dict(episodes=3, env_steps=0))
    assert not covers(config, dict(episodes=5, env_steps=25)) and not covers(config, dict(episodes=4, env_steps=26))
    assert covers(run(env_steps=0).config, dict(episodes=4, env_steps=10 ** 9))


def test_a_stage_keeps_the_episodes_begun_within_its_steps_and_its_episodes():
    staged = stage(run(), dict(episodes=3, env_steps=25))
    assert staged.path == "somewhere" and staged.df.index.tolist() == list(range(len(staged.df)))
    assert list(staged.df.columns) == list(run().df.columns)
    assert staged.df.groupby("seed")["episode"].max().tolist() == [3, 3, 2, 2]   # seed 2's third begins at 40
    assert staged.config["run"] == {"env": "square", "episodes": 3, "env_steps": 25, "seeds": [0, 1, 2, 3]}
    assert staged.config["agent"] == {} and run().config["run"]["episodes"] == 4  # the run's own config untouched
    assert stage(run(), dict(episodes=4, env_steps=20)).df.groupby("seed")["episode"].max().tolist() == [3, 4, 1, 2]
    assert len(stage(run(), dict(episodes=3, env_steps=0)).df) == 12


def test_each_domains_objective_by_kind():
    square = objective("square")
    assert square == Objective("steps to threshold", "steps to threshold (mean steps per episode <= 25 over 10 "
                               "episodes; a seed that never met it: the budget), IQM over seeds", "minimize",
                               domain("square").threshold(None), "steps")
    assert objective("square", "measure", window=7) == Objective(
        "steps per episode at budget", "steps per episode at budget (mean of each seed's last 7 episodes), IQM over "
        "seeds", "minimize", None, "steps", 7)
    assert objective("square", "report", measure="steps").threshold is None        # a measure named: no threshold
    cartpole = objective("gym:CartPole-v1")
    assert cartpole.threshold.value == 195 and cartpole.column == "return" and cartpole.direction == "minimize"
    assert objective("gym:CartPole-v1", "measure").direction == "maximize"
    assert objective("gym:Pendulum-v1") == at_budget_objective("return", "return per episode", "maximize", 10)   # the report's window
    liq = objective("liquidation", "measure", 20, measure="noise_free_cost_ratio")
    assert (liq.column, liq.name, liq.direction, liq.window) == ("noise_free_cost_ratio",
                                                                 "noise-free ac_cost / U* at budget", "minimize", 20)
    with pytest.raises(ValueError) as err:
        objective("square", "best")
    assert str(err.value) == "objective must be 'report', 'measure' or 'worst', got 'best'"


def test_the_worst_objective_names_its_ends():
    stages = [dict(episodes=100, env_steps=0), dict(episodes=1000, env_steps=0), dict(episodes=2500, env_steps=0)]
    worst = objective("liquidation", "worst", 50, stages)
    label = domain("liquidation").measure(None)[1]
    assert worst == Objective(f"worst {label}", f"worst {label} after the first stage (each seed's mean of its last "
                              "50 episodes before 1,000, 2,500; the worst of these), IQM over seeds", "minimize", None,
                              "cost_ratio", 50, ((1000, 0), (2500, 0)))
    assert objective("gym:Pendulum-v1", "worst", 5, stages).direction == "maximize"
    by_steps = worst_objective("x", "x", "maximize", 5, [dict(episodes=9, env_steps=s) for s in (10, 2000, 30000)],
                               "; a note")
    assert by_steps.stages == ((9, 2000), (9, 30000)) and by_steps.direction == "maximize"
    assert by_steps.text == ("worst x after the first stage (each seed's mean of its last 5 episodes before 2,000 "
                             "steps, 30,000 steps; the worst of these; a note), IQM over seeds")
    one = worst_objective("x", "x", "minimize", 5, stages[:2])
    assert one.stages == ((1000, 0),) and "before 1,000; the worst" in one.text
    for few in (stages[:1], []):
        with pytest.raises(ValueError) as err:
            objective("liquidation", "worst", 50, few)
        assert str(err.value) == "objective 'worst' needs at least two stages: it scores the stages after the first"
    noted = at_budget_objective("c", "a label", "minimize", 3, "; why")
    assert noted == Objective("a label at budget", "a label at budget (mean of each seed's last 3 episodes; why), IQM "
                              "over seeds", "minimize", None, "c", 3)
