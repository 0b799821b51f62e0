"""Liquidation on one reward (envs/liquidation/one_reward.py): its studies' command lines, the
windows of its two budgets on runs whose values are known, and its claims' verdicts."""
import numpy as np
import pandas as pd
import pytest

from trl_dgpq.analysis.claims import MET, NOT_MET, UNDECIDED, judge
from trl_dgpq.analysis.runs import Run
from trl_dgpq.envs.liquidation import one_reward as o

SEEDS = list(range(50, 60))


def frame(cost, seeds=SEEDS, episodes=5000, steps=60) -> pd.DataFrame:
    """Rows of seeds x episodes; ``cost(seed, episode)`` (arrays) the paired cost ratio, the noise-free
    one 0.5 above it; ``steps`` per episode (or a function of the episodes)."""
    s, e = (a.ravel() for a in np.meshgrid(seeds, np.arange(1, episodes + 1), indexing="ij"))
    c = np.broadcast_to(np.asarray(cost(s, e), dtype=float), s.shape)
    return pd.DataFrame(dict(seed=s, episode=e, steps=steps(e) if callable(steps) else steps, wall_s=0.06,
                             cost_ratio=c, noise_free_cost_ratio=c + 0.5))


def test_the_steps_budget_is_each_seeds_last_50_episodes_ended_by_its_18000th_step():
    # episodes of 60 steps: 300 end by step 18,000, the last 50 are 251-300
    got = o.in_budget(frame(lambda s, e: e, seeds=[50, 51], episodes=400), "steps")
    assert sorted(got[got.seed == 50].episode) == list(range(251, 301))
    # seed 51 at 59 steps an episode for its first 100 (5,900): episode 301 ends at step 17,960, 302 at 18,020
    uneven = frame(lambda s, e: e, seeds=[51], episodes=400, steps=lambda e: np.where(e <= 100, 59, 60))
    assert list(o.in_budget(uneven, "steps").episode) == list(range(252, 302))
    # an episode ending exactly on step 18,000 counts; one ending a step after does not
    assert o.in_budget(frame(lambda s, e: e, seeds=[52], episodes=300), "steps").episode.max() == 300
    assert o.per_seed(frame(lambda s, e: e * 1.0, seeds=[53], episodes=310), "steps")[0] == pytest.approx(275.5)


def test_the_episodes_budget_is_the_last_1000_of_5000_and_a_short_seed_is_refused():
    got = o.in_budget(frame(lambda s, e: e, seeds=[50], episodes=5000), "episodes")
    assert (got.episode.min(), got.episode.max(), len(got)) == (4001, 5000, 1000)
    assert list(o.in_budget(frame(lambda s, e: e, seeds=[50], episodes=100), "episodes").episode) == \
        list(range(51, 101))                                               # a small scale: its second half
    assert o.in_budget(frame(lambda s, e: e, seeds=[50], episodes=101), "episodes").episode.min() == 51
    longer = o.in_budget(frame(lambda s, e: e, seeds=[50], episodes=6000), "episodes")   # judged at 5,000 still
    assert (longer.episode.min(), longer.episode.max()) == (4001, 5000)
    with pytest.raises(ValueError, match="short of 18,000"):
        o.in_budget(frame(lambda s, e: e, seeds=[50], episodes=299), "steps")
    ragged = pd.concat([frame(lambda s, e: e, seeds=[50], episodes=5000), frame(lambda s, e: e, seeds=[51],
                                                                                episodes=4000)])
    with pytest.raises(ValueError, match="different episodes"):
        o.in_budget(ragged, "episodes")


def test_every_study_runs_the_same_protocol_from_its_learners_shortfall_preset():
    from trl_dgpq.commands.tune import make_parser
    from trl_dgpq.selection import REPORTING, as_seeds
    assert len(o.STUDIES) == 8 and {(w, r) for _, w, r in o.STUDIES} == {(w, r) for w in o.LEARNERS for r in o.REWARDS}
    parsed = {s: make_parser().parse_args(o.study_command(s, w, r)) for s, w, r in o.STUDIES}
    for (study, who, reward), args in zip(o.STUDIES, parsed.values()):
        assert (args.agent, args.reward, args.preset, args.write_preset) == (who, reward, "shortfall",
                                                                            f"{reward}-validated")
        assert (args.trials, args.env_steps, args.window, args.validate, args.objective) == \
            ("30", "18000", "50", 3, "measure")
        assert not set(as_seeds(args.seeds) + as_seeds(args.validation_seeds)) & set(REPORTING)
        assert args.out.endswith(study)
    td3 = parsed["liq1-td3-impact"]
    assert td3.actor_hidden == td3.critic_hidden == "24,48"       # DDPG's widths
    assert parsed["liq1-ddpg-impact"].actor_hidden is None


def test_the_plan_runs_each_learner_on_each_reward_with_its_studys_preset():
    plan = o.plan()               # built now, not at import (a mutation test switches a mutant on after the imports)
    planned = {n: settings for n, settings, *_ in plan}
    assert len(planned) == 8 + 2 + 2 and plan == o.REPRODUCE
    own = {n: scales[0] for n, _, *scales in plan if scales}          # TD3 past its random steps at the quick scale
    assert own == {"liq1-td3-shortfall": o.TD3_SCALES, "liq1-td3-impact": o.TD3_SCALES}
    assert o.TD3_SCALES == {**o.SCALES, "quick": (2, 70)}
    assert planned["liq1-ddpg-impact"] == dict(agent="ddpg", preset="impact-validated")
    assert planned["liq1-td3-shortfall"] == dict(agent="td3", preset="shortfall-validated")
    assert planned["liq1-dgpq-flat"] == dict(agent="dgpq", preset="flat") and planned["liq1-twap"] == dict(agent="twap")
    assert o.FIRST_SEED == 50 and o.SCALES["report"] == (10, 5000)


def runs_with(cost) -> dict:
    """Every planned experiment on seeds 50-59 for 5,000 episodes, ``cost(name, seed, episode)``."""
    out = {}
    for n, settings, *_ in o.plan():
        reward = "impact" if n.endswith("-impact") or n.endswith(("-flat", "-steady")) else "shortfall"
        config = {"run": dict(env="liquidation", agent=settings["agent"], preset=settings.get("preset", "shortfall"),
                              seeds=SEEDS), "env": dict(reward=reward), "agent": {}}
        out[n] = Run(None, frame(lambda s, e, n=n: cost(n, s, e)), config)
    return out


def test_the_claims_judge_each_pair_in_its_budgets_window():
    # to episode 300, then after: DGPQ 1.10, then 1.25 (it drifts up); DQN 1.20, then 1.07; DDPG 1.5, then
    # 1.01; TD3 1.30, then 1.25 +- 0.01 by seed (undecided against DGPQ there); impact runs cost 0.02 less
    # than their shortfall twins, seed for seed. DGPQ is ahead of all at the steps budget, of none after.
    early = lambda before, after: lambda s, e: np.where(e <= 300, before, after)  # noqa: E731
    base = {"dgpq": early(1.10, 1.25), "dqn": early(1.20, 1.07), "ddpg": early(1.5, 1.01),
            "td3": lambda s, e: np.where(e <= 300, 1.30, 1.25 + np.where(s % 2, 0.01, -0.01))}

    def cost(n, s, e):
        who = n.removeprefix("liq1-").split("-")[0]
        # impact runs 0.02 cheaper than their shortfall twins; DQN's only to episode 300, 0.02 dearer after
        impact = (np.where(e <= 300, -0.02, 0.02) if who == "dqn" else -0.02) if n.endswith("-impact") else 0.0
        return base[who](s, e) + impact + 1e-4 * s if who in base else 1.0 + 0 * e

    runs = runs_with(cost)
    got = {j.claim.key: j for j in (judge(c, runs, "report", set(runs)) for c in o.declared_claims())}
    assert len(got) == 20
    claim = got["liquidation-reward/impact/steps/dgpq-vs-td3"]
    assert (claim.claim.source, claim.claim.statement) == ("this suite", "on the impact reward at 18,000 env steps "
                                                            "(last 50 episodes), DGPQ costs less than TD3, each with its "
                                                            "validated study's preset (P(improvement) of each seed's "
                                                            "mean paired ac_cost / U*)")
    assert claim.ours == "1.00 (P(improvement) over 10 x 10 seeds [95 % CI])"
    buys = got["liquidation-reward/dqn/episodes/impact-vs-shortfall"]
    assert buys.claim.statement == ("at 5,000 episodes (last 1,000), DQN trained on the impact reward costs less than "
                                    "DQN trained on the shortfall reward (what the model-based reward buys it; "
                                    "P(improvement) of each seed's mean paired ac_cost / U*)")
    assert buys.claim.source == "this suite" and buys.ours.startswith("0.00")
    for reward in o.REWARDS:
        assert got[f"liquidation-reward/{reward}/steps/dgpq-vs-dqn"].verdict == MET
        assert got[f"liquidation-reward/{reward}/steps/dgpq-vs-ddpg"].verdict == MET
        assert got[f"liquidation-reward/{reward}/episodes/dgpq-vs-ddpg"].verdict == NOT_MET
        assert got[f"liquidation-reward/{reward}/episodes/dgpq-vs-td3"].verdict == UNDECIDED
        assert got[f"liquidation-reward/{reward}/steps/dgpq-vs-td3"].verdict == MET
        assert got[f"liquidation-reward/{reward}/episodes/dgpq-vs-dqn"].verdict == NOT_MET
    for who in o.LEARNERS:
        assert got[f"liquidation-reward/{who}/episodes/impact-vs-shortfall"].verdict == (NOT_MET if who == "dqn" else MET)
        assert got[f"liquidation-reward/{who}/steps/impact-vs-shortfall"].verdict == MET
    # the impact runs use the model: their claims are variants, the shortfall ones are not
    assert got["liquidation-reward/impact/steps/dgpq-vs-dqn"].variant
    assert got["liquidation-reward/dqn/steps/impact-vs-shortfall"].variant
    assert not got["liquidation-reward/shortfall/steps/dgpq-vs-dqn"].variant


def test_the_section_names_the_lowest_learner_per_reward_and_budget(tmp_path):
    # at the steps budget DGPQ 1.05 and DQN 1.06 +- 0.02 by seed (undecided); after, DDPG 1.01, DQN 1.20, DGPQ 1.3; TD3 1.4, but 1.5 in episodes 3,001-3,500 (a block of 500 worse than a block of 1,000 says)
    runs = runs_with(lambda n, s, e: {"dgpq": np.where(e <= 300, 1.05, 1.3), "dqn": np.where(e <= 300, 1.06 + np.where(s % 2, 0.02, -0.02),
                                                                          1.2),
                                      "ddpg": np.where(e <= 300, 1.3, 1.01),
                                      "td3": 1.4 + np.where((e > 3000) & (e <= 3500), 0.1, 0)}
                     .get(n.removeprefix("liq1-").split("-")[0], 1.0 + 0 * e) + 1e-4 * s)

    class Said:   # a judged claim, as the section sees it
        def __init__(self, text):
            self.text = text

        def bullet(self):
            return self.text
    text = o.reproduce_section(runs, tmp_path, "label", "title", [Said("- one"), Said("- two")])
    lines = text.splitlines()
    assert lines[:6] == [f"## {o.TITLE}", "", "label", "", "- one", "- two"]
    lines[4:6] = [""]                # the lines below as without claims
    assert lines[5].startswith("- Lowest IQM at 18,000 env steps (last 50 episodes): on shortfall, DGPQ (P(improves on "
                               "DQN, the next) 0.50 [")
    assert lines[6] == ("- Lowest IQM at 5,000 episodes (last 1,000): on shortfall, DDPG (P(improves on DQN, the next) "
                        "1.00); on impact, DDPG (P(improves on DQN, the next) 1.00).")
    assert lines[8] == ("| run | reward | preset | paired ac_cost / U* at 18,000 env steps (last 50 episodes) | "
                        "noise-free ac_cost / U* at 18,000 env steps (last 50 episodes) | paired ac_cost / U* at 5,000 "
                        "episodes (last 1,000) | noise-free ac_cost / U* at 5,000 episodes (last 1,000) | worst block "
                        "of 500 after episode 1,000 over the best (noise-free) | ms per seed-step |")
    assert lines[9] == "|---|---|---|---|---|---|---|---|---|"
    rows = [line for line in lines[10:] if line.startswith("| ")]
    assert [r.split(" | ")[0][2:] for r in rows] == [n.removeprefix("liq1-") for n, *_ in o.plan()
                                                     if not n.endswith("ac-optimal")]     # the optimum pairs, no row
    assert ("| ddpg-impact | impact | impact-validated | 1.305 [1.305, 1.306] | 1.805 [1.805, 1.806] | 1.015 "
            "[1.015, 1.016] | 1.515 [1.515, 1.516] | 1.0000 | 1.00 |") in rows
    td3 = next(r for r in rows if r.startswith("| td3-impact |")).split(" | ")
    assert td3[-2].startswith("1.0525 ")   # 2.005 / 1.905 (noise-free: 0.5 over the paired, 1.4 then 1.5; seed 50)
    assert lines[-1] == ("Each cell: IQM over seeds of each seed's mean in the window [95 % CI]; the paired ratio takes "
                         "out the price noise the AC optimum pays on the same path.")
    # a run shorter than the steps budget (a small scale): "-" there, its second half for the other
    short = {n: Run(None, r.df[r.df.episode <= 100], r.config) for n, r in runs.items()}
    text = o.reproduce_section(short, tmp_path, "label", "title", [])
    assert ("- Lowest IQM at 18,000 env steps (last 50 episodes): not measured, ddpg, dgpq, dqn, td3 ran shorter.\n"
            in text)
    assert "- Lowest IQM at 5,000 episodes (last 1,000): on shortfall, DGPQ (P(improves on DQN, the next) 0.50" in text
    assert "| twap | shortfall | shortfall | - | - | 1.005 [1.005, 1.006] | 1.505 [1.505, 1.506] | - | 1.00 |" in text


def test_the_domain_page_shows_a_studys_line_as_the_module_writes_it():
    import shlex
    from pathlib import Path
    page = (Path(__file__).parents[1] / "docs" / "domains" / "liquidation.md").read_text()
    assert "python scripts/tune.py " + shlex.join(o.study_command("liq1-dqn-impact", "dqn", "impact")) in page
