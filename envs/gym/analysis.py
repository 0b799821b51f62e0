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
TITLE = "DGPQ against DQN on gymnasium's classic control"
# the README's paragraph on the domain: words, no numbers (those come from the data)
SUMMARY = ('CartPole, MountainCar and Acrobot: each learner on its default preset and on the `tuned` one its own'
           ' study wrote (the same trial budget, env-step budget and tuning seeds for both, validated on other '
           "seeds), judged by rliable's probability that a DGPQ seed needs fewer env steps to the threshold than"
           " a DQN seed; and DQN with rl-baselines3-zoo's settings at the zoo's budgets.")
# DGPQ against DQN (issues 11, 27): each learner on its default preset and on the `tuned` one a
# study wrote (where there is one), at the comparison's budgets; and DQN with rl-baselines3-zoo's
# settings at the zoo's own budgets (the "zoo" preset; bench_parity.py runs SB3's side of it).
BUDGETS = {"CartPole-v1": 20_000, "MountainCar-v0": 30_000, "Acrobot-v1": 20_000}
CAP = 100_000  # episodes: each seed's env-step budget ends it


QUICK_STEPS = 1_100   # env steps per seed at the quick scale: past every DQN preset's first update (1,024)


def budget_sizes(budget: int, smoke: bool) -> dict:
    """(seeds, episodes, env steps per seed) per scale; the smoke scale runs one task only. The quick
    scale checks that each experiment runs and learns (it decides no claim): 2 seeds, ``QUICK_STEPS`` each."""
    sizes = {"quick": (2, CAP, QUICK_STEPS), "full": (10, CAP, budget), "report": (10, CAP, budget)}
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
SCALES = {"smoke": (1, CAP, "300"), "quick": (2, CAP, f"{QUICK_STEPS:,}"),
          **{s: (10, CAP, "20,000-120,000") for s in ("full", "report")}}   # for the label only


def steps_to(name: str):
    """Per seed: env steps to the task's threshold within the budget, the budget if never."""
    def per_seed(runs):
        from trl_dgpq.analysis.summary import steps_to_threshold
        run = runs[name]
        budget = run.config["run"]["env_steps"]
        return steps_to_threshold(run.df, THRESHOLDS[run.env_id], budget).fillna(budget).to_numpy()
    return per_seed


def faster(dgpq: str, dqn: str):
    """The claim's measure: P(a DGPQ seed needs fewer env steps to the threshold than a DQN seed)."""
    def measure(runs):
        from trl_dgpq.analysis.claims import improvement_interval
        return improvement_interval(steps_to(dgpq)(runs), steps_to(dqn)(runs), lower_is_better=True)
    return measure


def declared_claims() -> list:
    """This suite's claim, "DGPQ needs fewer env steps to the threshold than DQN", per task,
    default against default and tuned against tuned (where both have a tuned preset)."""
    from trl_dgpq.analysis.claims import Bound, Claim
    names = {name for name, *_ in REPRODUCE}
    out = []
    for env_id, budget in BUDGETS.items():
        tag = env_id.split("-")[0].lower()
        for kind, suffix in (("default", ""), ("tuned", "-tuned")):
            dgpq, dqn = f"{tag}-dgpq{suffix}", f"{tag}-dqn{suffix}"
            if dgpq in names and dqn in names:
                out.append(Claim(f"gym/{tag}/{kind}", "this suite", f"{env_id}, {kind} DGPQ needs fewer env steps "
                                 f"to the threshold ({THRESHOLDS[env_id].text}) than {kind} DQN, within {budget:,} "
                                 "per seed", Bound(0.5, higher_is_better=True), faster(dgpq, dqn), (dgpq, dqn),
                                 fmt="{:.2f}"))
    return out


CLAIMS = declared_claims()


def reproduce_section(runs: dict, out: Path, label: str, title: str, judged: list) -> str:
    """REPORT.md's section on DGPQ against DQN; ``runs``: {name in REPRODUCE: Run}; ``judged``: the
    verdicts of ``CLAIMS``."""
    from trl_dgpq.analysis.report import report
    parts = [f"## DGPQ against DQN (gymnasium classic control)\n\n{label}\n"]
    for folder, group, what in (
            ("gym", {n: r for n, r in runs.items() if not n.endswith("-zoo")},
             "Each learner on its default preset and on its `tuned` one (an Optuna study's best, validated)."),
            ("gym-zoo", {n: r for n, r in runs.items() if n.endswith("-zoo")},
             "DQN with rl-baselines3-zoo's settings at the zoo's budgets (parity with Stable-Baselines3: "
             "`scripts/bench_parity.py`).")):
        if not group:
            continue
        written, text = report(list(group.values()), list(group), out / folder)
        text = text.split("\n", 1)[1].replace("\n## ", "\n### ").replace("](profiles.png)",
                                                                         f"]({folder}/profiles.png)")
        figures = " ".join(f"![{p.stem}]({folder}/{p.name})" for p in written
                           if p.suffix == ".png" and p.name.startswith("compare-"))
        parts += [what, text, figures, ""]
    if judged:
        parts += ["Our claim, \"DGPQ needs fewer environment steps than DQN\", default against default and "
                  "tuned against tuned:", "", *[j.bullet() for j in judged], ""]
    return "\n".join(parts)
