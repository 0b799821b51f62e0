"""envs/gym/analysis.py's claim, its measure and its experiments' sizes by hand, each function called
at test time (the module's CLAIMS and REPRODUCE are built at import)."""
from pathlib import Path

import pandas as pd
import pytest

from trl_dgpq.analysis.claims import Bound
from trl_dgpq.analysis.runs import Run
from trl_dgpq.envs.gym import analysis as ga


def cartpole(returns_per_seed, budget=2000, steps=20):
    """A CartPole run: seed i's episodes return ``returns_per_seed[i]`` in turn, each of ``steps`` steps."""
    rows = [dict(seed=s, episode=e + 1, steps=steps, **{"return": r}) for s, rs in enumerate(returns_per_seed)
            for e, r in enumerate(rs)]
    df = pd.DataFrame(rows)
    df["env_steps"] = df.groupby("seed")["steps"].cumsum()
    config = {"run": {"env": "gym:CartPole-v1", "agent": "dqn", "preset": "default",
                      "seeds": list(range(len(returns_per_seed))), "env_steps": budget}, "env": {}, "agent": {}}
    return Run(Path("runs/c"), df, config)


def test_steps_to_the_threshold_per_seed_or_the_runs_budget_if_never():
    """CartPole's threshold: a mean return of 195 over 10 episodes. Seed 0 returns 200 from its first
    episode (met at its 10th, 200 steps); seed 1 never; seed 2, 150 four times then 200, means 180, 185,
    190 and 195 over episodes 1-10 to 4-13: met at its 13th (260 steps), within a budget of 300, not 220."""
    runs = {"a": cartpole([[200] * 15, [10] * 15, [150] * 4 + [200] * 11], budget=300)}
    assert ga.steps_to("a")(runs).tolist() == [200, 300, 260]
    runs = {"a": cartpole([[200] * 15, [10] * 15, [150] * 4 + [200] * 11], budget=220)}
    assert ga.steps_to("a")(runs).tolist() == [200, 220, 220]


def test_faster_is_the_probability_a_dgpq_seed_needs_fewer_steps():
    runs = {"d": cartpole([[200] * 12] * 3), "q": cartpole([[10] * 12] * 3)}
    got = ga.faster("d", "q")(runs)
    assert (got.point, got.low, got.high) == (1.0, 1.0, 1.0)
    assert got.statistic == "P(improvement) over 3 x 3 seeds [95 % CI]"
    back = ga.faster("q", "d")(runs)
    assert (back.point, back.low, back.high) == (0.0, 0.0, 0.0)


def test_each_task_claims_dgpq_faster_default_against_default_and_tuned_against_tuned():
    claims = ga.declared_claims()
    names = {name for name, *_ in ga.reproductions()}
    keys = [c.key for c in claims]
    want = [f"gym/{tag}/{kind}" for tag in ("cartpole", "mountaincar", "acrobot") for kind in ("default", "tuned")
            if f"{tag}-dgpq{'-tuned' if kind == 'tuned' else ''}" in names
            and f"{tag}-dqn{'-tuned' if kind == 'tuned' else ''}" in names]
    assert keys == want and "gym/cartpole/default" in keys
    first = claims[0]
    assert first.source == "this suite" and first.rule == Bound(0.5, higher_is_better=True) and first.fmt == "{:.2f}"
    assert first.needs == ("cartpole-dgpq", "cartpole-dqn")
    assert first.statement == ("CartPole-v1, default DGPQ needs fewer env steps to the threshold (mean return >= 195 "
                               "over 10 episodes) than default DQN, within 20,000 per seed")
    runs = {"cartpole-dgpq": cartpole([[200] * 12] * 2), "cartpole-dqn": cartpole([[10] * 12] * 2)}
    assert first.measure(runs).point == 1.0
    tuned = [c for c in claims if c.key.endswith("/tuned")]
    assert all(c.needs == (c.needs[0], c.needs[0].replace("dgpq", "dqn")) and c.needs[0].endswith("-tuned")
               for c in tuned)
    assert all("tuned DGPQ" in c.statement and "than tuned DQN" in c.statement for c in tuned)


@pytest.mark.parametrize("smoke", [True, False])
def test_each_scale_runs_its_seeds_for_its_share_of_the_budget(smoke):
    sizes = ga.budget_sizes(20_000, smoke)
    assert sizes["quick"] == (2, ga.CAP, 1_100) and sizes["full"] == sizes["report"] == (10, ga.CAP, 20_000)
    assert ("smoke" in sizes) == smoke and (not smoke or sizes["smoke"] == (1, ga.CAP, 300))
    assert ga.budget_sizes(50_000, smoke)["quick"] == (2, ga.CAP, 1_100)


def test_the_reproduction_runs_each_learner_on_its_default_and_tuned_presets_and_dqn_at_the_zoos_budget():
    got = {name: (kw, sizes) for name, kw, sizes in ga.reproductions()}
    assert got["cartpole-dgpq"][0] == dict(env="gym:CartPole-v1", agent="dgpq", preset="default")
    assert got["cartpole-dqn-zoo"][0] == dict(env="gym:CartPole-v1", agent="dqn", preset="zoo")
    assert "smoke" in got["cartpole-dqn"][1] and "smoke" not in got["acrobot-dqn"][1]     # the first task only
    assert got["mountaincar-dqn"][1]["full"] == (10, ga.CAP, 30_000)
    assert got["acrobot-dqn-zoo"][1]["quick"] == (2, ga.CAP, 1_100)                     # as every task's
    assert got["acrobot-dqn-zoo"][1]["full"][2] > 20_000                                 # the zoo's own budget


def test_the_section_has_a_table_per_group_its_figures_under_their_folders_and_the_verdicts(tmp_path, monkeypatch):
    def run(agent, preset, returns):
        r = cartpole([returns] * 2)
        r.config["run"].update(agent=agent, preset=preset)
        r.df["wall_s"] = 0.1
        r.df["terminated"] = False
        return r
    runs = {"cartpole-dgpq": run("dgpq", "default", [200] * 12), "cartpole-dqn": run("dqn", "default", [10] * 12),
            "cartpole-dqn-zoo": run("dqn", "zoo", [100] * 12)}
    judged = [type("J", (), {"bullet": lambda self: "- a verdict"})()]
    text = ga.reproduce_section(runs, tmp_path, "the label", "the title", judged)
    parts = text.split("\n")
    assert parts[:4] == ["## DGPQ against DQN (gymnasium classic control)", "", "the label", ""]
    assert parts[4] == "Each learner on its default preset and on its `tuned` one (an Optuna study's best, validated)."
    assert "### gym:CartPole-v1" in parts and "## gym:CartPole-v1" not in parts      # one level down
    assert "| cartpole-dgpq | 2 |" in text and "| cartpole-dqn-zoo | 2 |" in text
    zoo = parts.index("DQN with rl-baselines3-zoo's settings at the zoo's budgets (parity with Stable-Baselines3: "
                      "`scripts/bench_parity.py`).")
    assert "| cartpole-dqn-zoo |" not in "\n".join(parts[:zoo]) and "| cartpole-dgpq |" not in "\n".join(parts[zoo:])
    figure = parts.index("![compare-gym-CartPole-v1](gym/compare-gym-CartPole-v1.png)")
    assert parts[figure + 1] == "" and "Environment steps to a threshold" not in text     # report's title dropped
    assert "![compare-gym-CartPole-v1](gym-zoo/compare-gym-CartPole-v1.png)" in parts
    assert (tmp_path / "gym" / "compare.md").exists() and (tmp_path / "gym-zoo" / "compare.md").exists()
    assert parts[-4:] == ["Our claim, \"DGPQ needs fewer environment steps than DQN\", default against default and "
                          "tuned against tuned:", "", "- a verdict", ""]
    assert "Our claim" not in ga.reproduce_section(runs, tmp_path, "l", "t", [])
    only = ga.reproduce_section({k: v for k, v in runs.items() if not k.endswith("-zoo")}, tmp_path / "o", "l", "t", [])
    assert "zoo's budgets" not in only and not (tmp_path / "o" / "gym-zoo").exists()
    zoo_only = ga.reproduce_section({"cartpole-dqn-zoo": runs["cartpole-dqn-zoo"]}, tmp_path / "z", "l", "t", [])
    assert "| cartpole-dqn-zoo | 2 |" in zoo_only and not (tmp_path / "z" / "gym").exists()


def test_two_tasks_put_their_figures_on_one_line_and_the_profiles_under_their_folder(tmp_path):
    runs = {}
    for env, tag in (("gym:CartPole-v1", "cartpole"), ("gym:MountainCar-v0", "mountaincar")):
        for agent, ret in (("dgpq", 200), ("dqn", 10)):
            r = cartpole([[ret] * 12] * 2)
            r.config["run"].update(env=env, agent=agent)
            r.df["wall_s"], r.df["terminated"] = 0.1, agent == "dgpq"
            runs[f"{tag}-{agent}"] = r
    parts = ga.reproduce_section(runs, tmp_path, "l", "t", []).split("\n")
    assert ("![compare-gym-CartPole-v1](gym/compare-gym-CartPole-v1.png) "
            "![compare-gym-MountainCar-v0](gym/compare-gym-MountainCar-v0.png)") in parts     # profiles.png not
    assert "![profiles](gym/profiles.png)" in parts and (tmp_path / "gym" / "profiles.png").exists()
