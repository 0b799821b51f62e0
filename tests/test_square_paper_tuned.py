"""The square on GWH14's reward, tuned and validated (envs/square/paper_tuned.py): its plan, and its
claims' measures on runs whose values are known."""
import pandas as pd
import pytest

from trl_dgpq.analysis.claims import AGREES, BELOW, MET, NO_LEARNING, judge
from trl_dgpq.analysis.runs import Run
from trl_dgpq.commands import reproduce
from trl_dgpq.envs.square import paper_tuned as m


def test_the_plan_is_each_learners_validated_preset_uncapped_within_the_budget():
    """The part as reproduce plans it: apart from the square's own experiments, seeds 30-49, 100
    episodes within 10,000 steps, each learner's validated preset, episodes capped at 20,000."""
    assert not any(n.startswith("square-pt") for n in reproduce.experiments("report", ["square"]))
    planned = reproduce.plan_settings("report", ["square-paper-tuned"])
    common = dict(env="square", seeds=list(range(30, 50)), episodes=100, env_steps=10_000, max_steps=20_000)
    assert planned == {"square-pt-dgpq": dict(common, agent="dgpq", preset="paper-validated"),
                       "square-pt-dqn": dict(common, agent="dqn", preset="paper-validated"),
                       "square-pt-random": dict(common, agent="random", preset="paper")}
    configs = reproduce.experiments("report", ["square-paper-tuned"])
    for name in ("square-pt-dgpq", "square-pt-dqn"):     # the study's preset itself: its reward and cap
        assert configs[name]["env"]["reward"] == "paper" and configs[name]["env"]["max_steps"] == 20_000
    assert reproduce.plan_settings("smoke", ["square-paper-tuned"])["square-pt-dqn"]["seeds"] == [30]


def run_of(name, steps, terminated=True, budget=10_000):
    """A run of seeds 10-29 whose episode e of seed s takes ``steps(s, e)`` steps."""
    rows = [dict(seed=s, episode=e, steps=steps(s, e), terminated=terminated if e == 1 else True, wall_s=0.01)
            for s in range(10, 30) for e in range(1, 101)]
    df = pd.DataFrame(rows)
    df["env_steps"] = df.groupby("seed")["steps"].cumsum()
    df = df[df.env_steps - df.steps < budget].reset_index(drop=True)   # the runner's: episodes begun within it
    config = {"run": {"env": "square", "agent": "dgpq", "preset": "paper-validated", "env_steps": budget},
              "env": {"reward": "paper", "max_steps": 20_000}, "agent": {}}
    return Run(None, df, config)


def test_the_claims_measure_what_they_say():
    runs = {"square-pt-dgpq": run_of("d", lambda s, e: 120 if e == 1 else 18),      # meets the threshold at once
            "square-pt-dqn": run_of("q", lambda s, e: 400 if e == 1 else 40 if e < 50 else 20),
            "square-pt-random": run_of("r", lambda s, e: 500)}
    got = {c.key: judge(c, runs, "report") for c in m.declared_claims()}
    assert got["square-paper-tuned/episode-1"].verdict == AGREES                   # 120 within 3x of 100
    assert got["square-paper-tuned/episodes-3+"].verdict == AGREES                 # 18 within 1.5x of 20
    assert got["square-paper-tuned/dgpq-vs-dqn"].verdict == MET
    # DGPQ: episodes 1-10 average (120 + 9 x 18) / 10 = 28.2 > 25; episodes 2-11 average 18, at 120 + 10 x 18
    assert m.to_threshold(runs["square-pt-dgpq"].df, 10_000).tolist() == [300.0] * 20
    slow = {**runs, "square-pt-dgpq": run_of("d", lambda s, e: 400 if e == 1 else 40)}
    assert m.to_threshold(slow["square-pt-dgpq"].df, 10_000).tolist() == [10_000.0] * 20   # never: the budget
    assert judge(m.declared_claims()[1], slow, "report").verdict == BELOW
    wander = {**runs, "square-pt-dgpq": run_of("d", lambda s, e: 500)}
    assert judge(m.declared_claims()[1], wander, "report").verdict == NO_LEARNING


def test_seeds_without_an_episode_three_are_censored_not_dropped():
    long = {"square-pt-dgpq": run_of("d", lambda s, e: 6_000 if s < 15 and e <= 2 else 18)}   # 5 seeds: budget gone
    got = m.later_episodes("square-pt-dgpq")(long)
    assert got.censored == "5 of 20 seeds ran no episode 3 within the budget" and got.point == 18


def test_episode_one_cut_before_the_goal_is_censored():
    cut = {"square-pt-dgpq": run_of("d", lambda s, e: 20_000 if e == 1 else 18, terminated=False, budget=30_000)}
    got = m.episode_one("square-pt-dgpq")(cut)
    assert got.censored == "20 of 20 seeds capped at 20000 steps" and got.top == float("inf")
    assert judge(m.declared_claims()[0], cut, "report").verdict == BELOW          # at least 10,000: beyond 3 x 100 either way


def test_the_section_names_each_run_and_its_measures(tmp_path):
    """The whole section by hand. DGPQ: 100 episodes in 120 + 99 x 18 = 1,902 steps at 0.01 s each, 0.53 ms
    per seed-step; DQN: 400 + 99 x 40 = 4,360 steps, 0.23 ms, never at the threshold (the budget);
    random: 20 episodes of 500 begin within the budget, 0.2 s over 10,000 steps, 0.02 ms, its first
    episode cut by the cap in every seed."""
    from trl_dgpq.analysis.claims import Judged
    runs = {"square-pt-dgpq": run_of("d", lambda s, e: 120 if e == 1 else 18),
            "square-pt-dqn": run_of("q", lambda s, e: 400 if e == 1 else 40),
            "square-pt-random": run_of("r", lambda s, e: 500, terminated=False)}
    runs["square-pt-random"].config["run"]["preset"] = "paper"
    claims = m.declared_claims()
    text = m.reproduce_section(runs, tmp_path, "label", "title", [Judged(c, "agrees", "ours", ()) for c in claims[:2]])
    assert text == (
        f"## {m.TITLE}\n\nlabel\n\n" + "\n".join(f"- GWH14: {c.statement} ({c.rule.text()}). Ours: ours -- **agrees**."
                                                  for c in claims[:2]) + "\n\n"
        "| run | preset | episode 1, steps (IQM [95 % CI]) | median steps of episodes 3+ (IQM over seeds) "
        "| seeds at the threshold within the budget | env steps to the threshold (IQM; never: the budget) "
        "| ms per seed-step |\n|---|---|---|---|---|---|---|\n"
        "| dgpq | paper-validated | 120 | 18.0 | 20 of 20 | 300 | 0.53 |\n"
        "| dqn | paper-validated | 400 | 40.0 | 0 of 20 | 10,000 | 0.23 |\n"
        "| random | paper | 500 (20 of 20 seeds capped at 20000 steps) | 500.0 | 0 of 20 | 10,000 | 0.02 |\n")


def test_the_section_counts_only_what_the_budget_saw():
    """Episodes begun within the 10,000-step budget run to their end. late: 9,760 steps, then ten of 25
    whose mean meets the threshold only at 10,010 steps, past the budget (never: the budget); three:
    episodes of 5,000, 4,000 and 2,000 (the third begun at 9,000), so episode 3 alone is "3+"; two:
    6,000 and 5,000, no episode 3 at all."""
    runs = {"square-pt-late": run_of("l", lambda s, e: 9_760 if e == 1 else 25),
            "square-pt-three": run_of("t", lambda s, e: {1: 5_000, 2: 4_000}.get(e, 2_000)),
            "square-pt-two": run_of("w", lambda s, e: 6_000 if e == 1 else 5_000)}
    assert runs["square-pt-late"].df.groupby("seed").env_steps.max().tolist() == [10_010] * 20
    rows = m.reproduce_section(runs, None, "", "", []).splitlines()[-3:]
    assert rows == ["| late | paper-validated | 9,760 | 25.0 | 0 of 20 | 10,000 | 0.01 |",
                    "| three | paper-validated | 5,000 | 2000.0 | 0 of 20 | 10,000 | 0.00 |",
                    "| two | paper-validated | 6,000 | - | 0 of 20 | 10,000 | 0.00 |"]
    assert m.to_threshold(runs["square-pt-late"].df, 10_000).tolist() == [10_000.0] * 20
    assert m.to_threshold(runs["square-pt-late"].df, 20_000).tolist() == [10_010.0] * 20
    assert m.to_threshold(runs["square-pt-late"].df, 10_000).dtype == float


def test_the_budget_of_a_run():
    runs = {"square-pt-dgpq": run_of("d", lambda s, e: 18)}
    assert m.budget_of(runs["square-pt-dgpq"]) == 10_000
    runs["square-pt-dgpq"].config["run"]["env_steps"] = 0            # no budget recorded: the part's own
    assert m.budget_of(runs["square-pt-dgpq"]) == m.BUDGET == 10_000
