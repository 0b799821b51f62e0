"""The square on GWH14's own reward, each learner tuned alike and validated, reproduced apart
(``reproduce --only square-paper-tuned``; ``APART`` in analysis.py). The plan and claims were
fixed here before either study ran, and registered once both had written ``paper-validated``.

GWH14's MDP pays -1 per step (``paper``). DGPQ and DQN each take the preset ``paper-validated``:
the winner of a 30-trial Optuna study from the ``paper`` preset (seeds 1000-1004, a 10,000-step
budget, episodes uncapped at 20,000 steps, the objective the env steps to the threshold), its 3
best trials and the base preset run again on the validation seeds 1005-1014, the best there kept
(``tune --validate 3``; envs/square/tuned.json records each study). A random walk is the trivial
baseline. 20 reporting seeds (30-49: 10-19 ran `paper` uncapped already, and a validation may
keep it), 100 episodes within a 10,000-step budget, episodes capped at 20,000 steps so that
episode 1 is never cut near GWH14's ~100 or the seed report's 1,000-5,000.

The claims, fixed here before any reporting run: GWH14's episode 1 (~100 steps) and episodes 3+
(~20), by the square's rules (analysis.py), on tuned DGPQ; and P(DGPQ reaches the threshold in
fewer env steps than DQN) above 0.5, a seed that never reached it counted at the budget.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from trl_dgpq.analysis import ms_per_seed_step, steps_to_threshold

from .analysis import NO_CAP, THRESHOLD, episode_one, later_episodes

BUDGET = 10_000
FIRST_SEED = 30         # 10-19 ran `paper` uncapped (square-paper-nocap), which a validation may keep
TITLE = "The square on GWH14's own reward, DGPQ and DQN tuned alike and validated"
SUMMARY = ("DGPQ and DQN on GWH14's reward (-1 per step), each with the preset its own 30-trial study chose and "
           "validated on other seeds, 20 seeds within a 10,000-step budget, episodes capped only at 20,000 steps; "
           "a random walk as the trivial baseline.")
SCALES = {"smoke": (1, 3, 600), "quick": (4, 10, 1000), "full": (20, 100, BUDGET), "report": (20, 100, BUDGET)}
LEARNERS = {"square-pt-dgpq": "dgpq", "square-pt-dqn": "dqn"}
REPRODUCE = [(name, dict(agent=agent, preset="paper-validated", max_steps=NO_CAP)) for name, agent in LEARNERS.items()]
REPRODUCE.append(("square-pt-random", dict(agent="random", preset="paper", max_steps=NO_CAP)))


def to_threshold(df: pd.DataFrame, budget: int) -> np.ndarray:
    """Each seed's env steps to the threshold; one that never met it within ``budget``: the budget."""
    return steps_to_threshold(df, THRESHOLD, budget).fillna(budget).to_numpy(float)


def budget_of(run) -> int:
    return int(run.config["run"]["env_steps"]) or BUDGET


def improvement(x: str = "square-pt-dgpq", y: str = "square-pt-dqn"):
    def measure(runs):
        from trl_dgpq.analysis.claims import improvement_interval
        return improvement_interval(to_threshold(runs[x].df, budget_of(runs[x])),
                                    to_threshold(runs[y].df, budget_of(runs[y])), lower_is_better=True)
    return measure


def declared_claims() -> list:
    from trl_dgpq.analysis.claims import Agrees, Bound, Claim
    reward = "run on GWH14's reward (-1 per step), tuned and validated, episodes capped at 20,000 steps"
    learner = "square-pt-dgpq"
    return [Claim("square-paper-tuned/episode-1", "GWH14", f"DGPQ reaches the goal in ~100 steps in episode 1; {reward}",
                  Agrees(100, 3, higher_is_better=False), episode_one(learner), (learner,)),
            Claim("square-paper-tuned/episodes-3+", "GWH14", "~20 steps per episode (the optimum ~17) within 2-3 "
                  f"episodes: each seed's median from episode 3 on; {reward}", Agrees(20, 1.5, higher_is_better=False),
                  later_episodes(learner), (learner,), baseline="square-pt-random"),
            Claim("square-paper-tuned/dgpq-vs-dqn", "this suite", "on GWH14's reward, each tuned alike and validated, "
                  "DGPQ reaches the threshold (mean steps per episode <= 25 over 10 episodes) in fewer env steps "
                  "than DQN (P(improvement); a seed that never did counts at the budget)", Bound(0.5, higher_is_better=True),
                  improvement(), ("square-pt-dgpq", "square-pt-dqn"), fmt="{:.2f}")]


CLAIMS = declared_claims()


def reproduce_section(runs: dict, out: Path, label: str, title: str, judged: list) -> str:
    from trl_dgpq.analysis.claims import seeds_interval
    rows = ["| run | preset | episode 1, steps (IQM [95 % CI]) | median steps of episodes 3+ (IQM over seeds) "
            "| seeds at the threshold within the budget | env steps to the threshold (IQM; never: the budget) "
            "| ms per seed-step |", "|---|---|---|---|---|---|---|"]
    for name, run in runs.items():
        df, budget = run.df, budget_of(run)
        one = episode_one(name)(runs)
        later = df[df.episode >= 3].groupby("seed")["steps"].median()
        reached = steps_to_threshold(df, THRESHOLD, budget)
        rows.append(f"| {name.removeprefix('square-pt-')} | {run.config['run']['preset']} | {one.text('{:,.0f}')}"
                    + (f" ({one.censored})" if one.censored else "")
                    + f" | {seeds_interval(later).text('{:.1f}') if len(later) else '-'}"
                    + f" | {int(reached.notna().sum())} of {len(reached)}"
                    + f" | {seeds_interval(to_threshold(df, budget)).text('{:,.0f}')} | {ms_per_seed_step(df):.2f} |")
    return (f"## {TITLE}\n\n{label}\n\n" + "\n".join(j.bullet() for j in judged) + "\n\n" + "\n".join(rows) + "\n")
