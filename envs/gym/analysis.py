"""What the analysis says about gymnasium envs: curves of the return; thresholds per id."""
from pathlib import Path

from trl_dgpq.analysis import Threshold

# What the agent sees ("unit" for DGPQ, "raw" for the neural learners) is its side of the
# task: DGPQ and DQN on one gym id share a table.
AGENT_SIDE_SETTINGS = ("observations",)
THRESHOLDS = {
    "CartPole-v1": Threshold("return", ">=", 195, 10, "mean return >= 195 over 10 episodes"),
    "MountainCar-v0": Threshold("terminated", ">=", 1, 1, "an episode reaches the flag"),
    "Acrobot-v1": Threshold("return", ">=", -100, 10, "mean return >= -100 over 10 episodes"),
}

# what "terminated" (gymnasium's, not the step cap) means per id, for the summary line
TERMINATED = {
    "CartPole-v1": "the pole fell or the cart left the track",
    "MountainCar-v0": "reached the flag",
    "Acrobot-v1": "swung the tip above the line",
}


# ------------------------------------------------------------ the reproduction (scripts/reproduce.py)
# DGPQ against DQN (issues 11, 27): each learner on its default preset and on the `tuned` one a
# study wrote (where there is one), at the comparison's budgets; and DQN with rl-baselines3-zoo's
# settings at the zoo's own budgets (the "zoo" preset; bench_parity.py runs SB3's side of it).
BUDGETS = {"CartPole-v1": 20_000, "MountainCar-v0": 30_000, "Acrobot-v1": 20_000}
CAP = 100_000  # episodes: each seed's env-step budget ends it


def budget_sizes(budget: int, smoke: bool) -> dict:
    """(seeds, episodes, env steps per seed) per scale; the smoke scale runs one task only."""
    sizes = {"quick": (3, CAP, budget // 4), "full": (10, CAP, budget), "report": (10, CAP, budget)}
    return {"smoke": (1, CAP, 300), **sizes} if smoke else sizes


def reproductions() -> list:
    from trl_dgpq.presets import TUNED, preset_table
    from .presets import ZOO_DQN
    out = []
    for k, (env_id, budget) in enumerate(BUDGETS.items()):
        env, tag = f"gym:{env_id}", env_id.split("-")[0].lower()
        for agent in ("dgpq", "dqn"):
            for preset in ("default", TUNED):
                if preset in preset_table(env, agent):
                    out.append((f"{tag}-{agent}" + ("-tuned" if preset == TUNED else ""),
                                dict(env=env, agent=agent, preset=preset), budget_sizes(budget, k == 0)))
        out.append((f"{tag}-dqn-zoo", dict(env=env, agent="dqn", preset="zoo"),
                    budget_sizes(ZOO_DQN[env_id]["n_timesteps"], k == 0)))
    return out


REPRODUCE = reproductions()
SCALES = {"smoke": (1, CAP, "300"), "quick": (3, CAP, "5,000-30,000"),
          **{s: (10, CAP, "20,000-120,000") for s in ("full", "report")}}   # for the label only


def claim(dgpq, dqn):
    """Whether "DGPQ needs fewer env steps to the threshold" holds for two runs on one task: P(a
    DGPQ seed improves on a DQN seed) with its 95 % CI (a seed that never met it: the budget);
    reproduced when the CI lies above 0.5."""
    from trl_dgpq.analysis.claims import Claim
    from trl_dgpq.analysis.stats import probability_of_improvement
    from trl_dgpq.analysis.summary import steps_to_threshold
    budget = dqn.config["run"]["env_steps"]
    threshold = THRESHOLDS[dqn.env_id]
    steps = [steps_to_threshold(r.df, threshold, budget).fillna(budget).to_numpy() for r in (dgpq, dqn)]
    p, low, high = probability_of_improvement(-steps[0], -steps[1])
    shown = ("DGPQ shown faster" if low > 0.5 else "DQN shown faster" if high < 0.5 else "neither shown faster")
    return Claim("this suite", f"{dqn.env_id}, {dgpq.preset} DGPQ needs fewer env steps to the threshold than "
                 f"{dqn.preset} DQN ({budget:,} steps per seed)",
                 f"P(DGPQ improves on DQN) = {p:.2f} [{low:.2f}, {high:.2f}]: {shown}",
                 "reproduced" if low > 0.5 else "not reproduced")


def claims(runs: dict) -> list:
    """Default against default and tuned against tuned, per task."""
    tags = [i.split("-")[0].lower() for i in BUDGETS]
    return [claim(runs[f"{t}-dgpq{s}"], runs[f"{t}-dqn{s}"]) for t in tags for s in ("", "-tuned")
            if f"{t}-dgpq{s}" in runs and f"{t}-dqn{s}" in runs]


def reproduce_section(runs: dict, out: Path, label: str, title: str) -> str:
    """REPORT.md's section on DGPQ against DQN; ``runs``: {name in REPRODUCE: Run}."""
    from trl_dgpq.analysis.report import report
    parts = [f"## DGPQ against DQN (gymnasium classic control; issues 11, 27)\n\n{label}\n"]
    for folder, group, what in (
            ("gym", {n: r for n, r in runs.items() if not n.endswith("-zoo")},
             "Each learner on its default preset and on its `tuned` one (an Optuna study's best, validated)."),
            ("gym-zoo", {n: r for n, r in runs.items() if n.endswith("-zoo")},
             "DQN with rl-baselines3-zoo's settings at the zoo's budgets (parity with Stable-Baselines3: "
             "`scripts/bench_parity.py`).")):
        if not group:
            continue
        written, text = report([r.path for r in group.values()], list(group), out / folder)
        text = text.split("\n", 1)[1].replace("\n## ", "\n### ").replace("](profiles.png)",
                                                                         f"]({folder}/profiles.png)")
        figures = " ".join(f"![{p.stem}]({folder}/{p.name})" for p in written
                           if p.suffix == ".png" and p.name.startswith("compare-"))
        parts += [what, text, figures, ""]
    found = claims(runs)
    if found:
        parts += ["Our claim, \"DGPQ needs fewer environment steps than DQN\", default against default and "
                  "tuned against tuned:", "", *[c.bullet() for c in found], ""]
    return "\n".join(parts)
