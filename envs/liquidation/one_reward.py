"""Liquidation on one reward: DGPQ, DQN, DDPG and TD3, each trained on the model-free ``shortfall``
reward and each on the ``impact`` reward (which uses the AC model: a documented variant), each
tuned by the same study and validated alike (issue 51, part 2). The plan, the studies and the
claims are fixed here before any of their runs; the part joins the reproduction (``APART`` in
analysis.py, ``reproduce --only liquidation-reward``) once its eight studies have written their
presets, as square-paper-tuned did.

**The studies** (``STUDIES``; ``study_command`` gives each one's ``trl-dgpq tune`` line): for each
learner and reward, 30 trials of the agent's own search space (``SEARCH_SPACE`` beside its config)
from its ``shortfall`` preset (the reward given on top for ``impact``), seeds 1000-1004, a budget
of 18,000 env steps (at least 300 episodes of up to 60 trades), scored by the paired cost ratio (ac_cost / U*,
each episode against the AC optimum on the same price path) averaged over the last 50 episodes of
the budget, IQM over the seeds; then the 3 best trials and the base preset again on the
validation seeds 1005-1014, the best there written as preset ``<reward>-validated``. Every study
runs with the same sampler seed, stages and pruner. TD3 runs at DDPG's widths (24, 48) in place of
the TD3 paper's 256 x 256: the two actor-critics then have networks of one size, and TD3 at
256 x 256 costs ~4 ms per seed-step against DDPG's ~1 (its 30-trial study and runs would take
over a day of one core). Everything a study does not search stays each learner's own (its
``shortfall`` preset, else its config's defaults): TD3's buffer, batch, learning start, Gaussian
noise and critic layout are not DDPG's, and DDPG and TD3 discount at 0.99 where DQN and DGPQ do
not (1.0, as the objective), differences the comparison keeps and names. Every preset is chosen
at 18,000 env steps and also judged at 5,000 episodes, a budget none was tuned for; and 5,000
episodes is fewer env steps for a learner that sells in fewer trades. DGPQ's hand-set ``flat`` and ``steady`` (the impact reward; chosen on seeds
1000-1001 and 2000-2003, never on reporting seeds) run beside the studies' presets, reported, not
claimed: their selection was not the others'.

**The runs**: 10 reporting seeds no liquidation run has used (50-59) x 5,000 episodes per learner
and reward, the AC optimum (which pairs every episode) and TWAP. Both budgets come from the same
runs: a learner's first 18,000 env steps do not depend on how long it runs on (its settings are
counts of steps, its streams per seed), so "at 18,000 env steps" is each seed's last 50 episodes
that ended by its 18,000th step (the studies' window), "at 5,000 episodes" its last 1,000.

**The claims** (each per seed, on the paired cost ratio in the budget's window, rliable's
P(improvement) against 0.5, lower cost better): at each budget and on each reward, P(DGPQ improves
on DQN), on DDPG and on TD3 (12); and at each budget, for each learner, P(it trained on ``impact``
improves on it trained on ``shortfall``): what the model-based reward buys it (8). The claims on
the impact reward use the model and are counted apart. Which learner is best at each budget is
read off the table of IQMs and these intervals (not a claim). The table adds the noise-free cost
ratio (the expected cost of the trades played) at both budgets, each seed's worst block of 500
episodes after episode 1,000 over its best (noise-free; the drift goal's measure) and the wall
time per seed-step.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from trl_dgpq.analysis import ms_per_seed_step

from .analysis import TD3_QUICK

LEARNERS = ("dgpq", "dqn", "ddpg", "td3")
RIVALS = ("dqn", "ddpg", "td3")
REWARDS = ("shortfall", "impact")
HAND_SET = ("flat", "steady")               # DGPQ's impact presets of earlier studies: in the table only
FIRST_SEED = 50
STEPS, STEP_WINDOW = 18_000, 50             # the studies' budget and window
EPISODES, LAST = 5_000, 1_000
BLOCK, SETTLE = 500, 1_000                  # the drift goal's blocks: the worst after episode 1,000 over the best
BUDGETS = {"steps": f"{STEPS:,} env steps (last {STEP_WINDOW} episodes)",
           "episodes": f"{EPISODES:,} episodes (last {LAST:,})"}
MEASURES = {"cost_ratio": "paired ac_cost / U*", "noise_free_cost_ratio": "noise-free ac_cost / U*"}
SMALL_TD3 = dict(actor_hidden=(24, 48), critic_hidden=(24, 48))    # DDPG's widths (DDPGConfig's defaults)
STUDY = dict(trials=30, seeds="1000-1004", env_steps=STEPS, episodes=100_000, objective="measure",
             window=STEP_WINDOW, validate=3, validation_seeds="1005-1014", sampler_seed=0)
SCALES = {"smoke": (1, 4), "quick": (2, 30), "full": (10, EPISODES), "report": (10, EPISODES)}
TD3_SCALES = {**SCALES, "quick": TD3_QUICK}   # quick: past TD3's 1,000 steps of random actions, so that it updates
TITLE = "Liquidation on one reward: DGPQ, DQN, DDPG and TD3 on `shortfall` and on `impact`, tuned alike"
SUMMARY = ("DGPQ, DQN, DDPG and TD3 (at DDPG's widths), each trained on the model-free shortfall reward and on the "
           "impact reward (which uses the AC model), each with the preset its own 30-trial study chose and "
           "validated on other seeds; 10 fresh seeds (50-59) x 5,000 episodes, judged on the paired cost ratio at "
           "18,000 env steps and at 5,000 episodes.")


def name(who: str, reward: str = "") -> str:
    return f"liq1-{who}" + (f"-{reward}" if reward else "")


def preset_of(reward: str) -> str:
    return f"{reward}-validated"


def settings_of(who: str, reward: str) -> dict:
    return dict(agent=who, preset=preset_of(reward))


STUDIES = [(f"liq1-{who}-{reward}", who, reward) for who in LEARNERS for reward in REWARDS]


def study_command(study: str, who: str, reward: str, out: str = "runs/tune") -> list:
    """The study's ``trl-dgpq tune`` arguments: run, then again with the same line to continue it;
    its last run validates and writes the preset."""
    s = STUDY
    args = ["--env", "liquidation", "--agent", who, "--preset", "shortfall", "--reward", reward,
            "--trials", str(s["trials"]), "--seeds", s["seeds"], "--env-steps", str(s["env_steps"]),
            "--episodes", str(s["episodes"]), "--objective", s["objective"], "--window", str(s["window"]),
            "--sampler-seed", str(s["sampler_seed"]), "--validate", str(s["validate"]),
            "--validation-seeds", s["validation_seeds"], "--write-preset", preset_of(reward),
            "--out", f"{out}/{study}"]
    if who == "td3":
        args += [f"--{k.replace('_', '-')}={','.join(map(str, v))}" for k, v in SMALL_TD3.items()]
    return args


def plan() -> list:
    """[(experiment, settings)]: each learner on each reward with its study's preset, DGPQ's hand-set
    impact presets, and the AC optimum (which pairs every episode) and TWAP."""
    return ([(name(who, reward), settings_of(who, reward), *([TD3_SCALES] if who == "td3" else []))
             for who in LEARNERS for reward in REWARDS]
            + [(name(f"dgpq-{p}"), dict(agent="dgpq", preset=p)) for p in HAND_SET]
            + [(name("ac-optimal"), dict(agent="ac-optimal")), (name("twap"), dict(agent="twap"))])


REPRODUCE = plan()


# ------------------------------------------------------------ measures
def in_budget(df: pd.DataFrame, budget: str) -> pd.DataFrame:
    """Each seed's episodes in ``budget``'s window: "steps", its last ``STEP_WINDOW`` episodes that
    ended by its ``STEPS``-th env step; "episodes", its last ``LAST`` of ``EPISODES`` (a shorter run,
    a small scale: its second half). A seed short of the budget is an error: never judged on less."""
    df = df.sort_values(["seed", "episode"])
    if budget == "steps":
        ended = df.groupby("seed")["steps"].cumsum()
        short = df.assign(ended=ended).groupby("seed")["ended"].max() < STEPS
        if short.any():
            raise ValueError(f"seed {short.idxmax()} ran {int(ended[df.seed == short.idxmax()].max()):,} env steps, "
                             f"short of {STEPS:,}")
        kept = df[ended <= STEPS]
        return kept.groupby("seed").tail(STEP_WINDOW)
    runs_to = df.groupby("seed")["episode"].max()
    if runs_to.nunique() != 1:
        raise ValueError(f"the seeds ran to different episodes ({runs_to.min()}-{runs_to.max()})")
    end = int(runs_to.iloc[0])
    if end >= EPISODES:      # a longer run (lengthened, reused) is judged at this budget too, not at its end
        return df[(df.episode > EPISODES - LAST) & (df.episode <= EPISODES)]
    return df[df.episode > end // 2]


def per_seed(df: pd.DataFrame, budget: str, column: str = "cost_ratio") -> np.ndarray:
    """Each seed's mean of ``column`` in ``budget``'s window, by seed."""
    return in_budget(df, budget).groupby("seed")[column].mean().to_numpy()


def improvement(x: str, y: str, budget: str):
    """P(run x costs less than run y): each seed's mean paired cost ratio in ``budget``'s window."""
    def measure(runs):
        from trl_dgpq.analysis.claims import improvement_interval
        return improvement_interval(per_seed(runs[x].df, budget), per_seed(runs[y].df, budget), lower_is_better=True)
    return measure


def declared_claims() -> list:
    from trl_dgpq.analysis.claims import Bound, Claim
    out = []
    for budget, words in BUDGETS.items():
        for reward in REWARDS:
            dgpq = name("dgpq", reward)
            out += [Claim(f"liquidation-reward/{reward}/{budget}/dgpq-vs-{rival}", "this suite",
                          f"on the {reward} reward at {words}, DGPQ costs less than {rival.upper()}, each with its "
                          "validated study's preset (P(improvement) of each seed's mean paired ac_cost / U*)",
                          Bound(0.5, higher_is_better=True), improvement(dgpq, name(rival, reward), budget),
                          (dgpq, name(rival, reward)), fmt="{:.2f}") for rival in RIVALS]
        out += [Claim(f"liquidation-reward/{who}/{budget}/impact-vs-shortfall", "this suite",
                      f"at {words}, {who.upper()} trained on the impact reward costs less than {who.upper()} trained "
                      "on the shortfall reward (what the model-based reward buys it; P(improvement) of each seed's "
                      "mean paired ac_cost / U*)", Bound(0.5, higher_is_better=True),
                      improvement(name(who, "impact"), name(who, "shortfall"), budget),
                      (name(who, "impact"), name(who, "shortfall")), fmt="{:.2f}") for who in LEARNERS]
    return out


CLAIMS = declared_claims()


# ------------------------------------------------------------ the section
def learners_of(runs: dict) -> list:
    return [n for n in runs if not n.endswith(("-ac-optimal", "-twap"))]


def cell(df: pd.DataFrame, budget: str, column: str) -> str:
    """IQM [95 % CI] over seeds in ``budget``'s window; "-" where the runs are short of it (a small scale)."""
    from trl_dgpq.analysis.claims import seeds_interval
    try:
        return seeds_interval(per_seed(df, budget, column)).text("{:.3f}")
    except ValueError:
        return "-"


def worst_block(df: pd.DataFrame) -> str:
    """IQM [95 % CI] over seeds of each seed's worst block of ``BLOCK`` episodes after episode ``SETTLE``
    over its best (noise-free, analysis.py's drift); "-" where no block lies there (a short run)."""
    from trl_dgpq.analysis.claims import seeds_interval

    from .analysis import noise_free_drift
    got = [noise_free_drift(g, BLOCK, SETTLE) for _, g in df.groupby("seed")]
    values = [d["worst_over_best"] for d in got if d is not None]
    return seeds_interval(values).text("{:.4f}") if len(values) and np.isfinite(values).any() else "-"


def table(runs: dict) -> str:
    cols = [(b, c) for b in BUDGETS for c in MEASURES]
    rows = ["| run | reward | preset | " + " | ".join(f"{MEASURES[c]} at {BUDGETS[b]}" for b, c in cols)
            + f" | worst block of {BLOCK} after episode {SETTLE:,} over the best (noise-free) | ms per seed-step |",
            "|---|---|---|" + "---|" * len(cols) + "---|---|"]
    for n in learners_of(runs) + [name("twap")]:
        run = runs[n]
        cells = [cell(run.df, b, c) for b, c in cols] + [worst_block(run.df)]
        rows.append(f"| {n.removeprefix('liq1-')} | {run.config['env']['reward']} | {run.config['run']['preset']} | "
                    + " | ".join(cells) + f" | {ms_per_seed_step(run.df):.2f} |")
    return ("\n".join(rows) + "\n\nEach cell: IQM over seeds of each seed's mean in the window [95 % CI]; the "
            "paired ratio takes out the price noise the AC optimum pays on the same path.\n")


def best_at(runs: dict, budget: str) -> str:
    """The learner with the lowest IQM paired cost ratio at ``budget`` per reward, and its
    P(improvement) on the next."""
    from trl_dgpq.analysis.claims import improvement_interval, seeds_interval
    out = []
    short = [w for w in LEARNERS for r in REWARDS if cell(runs[name(w, r)].df, budget, "cost_ratio") == "-"]
    if short:
        return f"- Lowest IQM at {BUDGETS[budget]}: not measured, {', '.join(sorted(set(short)))} ran shorter."
    for reward in REWARDS:
        ranked = sorted(LEARNERS, key=lambda w: seeds_interval(per_seed(runs[name(w, reward)].df, budget)).point)
        first, second = ranked[:2]
        p = improvement_interval(per_seed(runs[name(first, reward)].df, budget),
                                 per_seed(runs[name(second, reward)].df, budget), lower_is_better=True)
        out.append(f"on {reward}, {first.upper()} (P(improves on {second.upper()}, the next) {p.text('{:.2f}')})")
    return f"- Lowest IQM at {BUDGETS[budget]}: " + "; ".join(out) + "."


def reproduce_section(runs: dict, out: Path, label: str, title: str, judged: list) -> str:
    return (f"## {TITLE}\n\n{label}\n\n" + "\n".join(j.bullet() for j in judged) + "\n"
            + "\n".join(best_at(runs, b) for b in BUDGETS) + "\n\n" + table(runs))


if __name__ == "__main__":    # the eight studies' command lines, to run (each continues with the same line)
    import shlex
    for study, who, reward in STUDIES:
        print("python scripts/tune.py " + shlex.join(study_command(study, who, reward)))
