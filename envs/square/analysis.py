"""What the analysis says about the square: steps per episode, and a threshold near the optimum (~17)."""
from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path
from typing import Optional

import numpy as np
import pandas as pd

from trl_dgpq.analysis import Threshold, kernel_fits_per_seed, ms_per_seed_step


MEASURE = ("steps", "steps per episode")
MEASURE_LOWER_IS_BETTER = True  # the at-budget scores (report: IQM, P(improvement), profiles) are negated
TERMINATED = "reached the goal"
THRESHOLD = Threshold("steps", "<=", 25, 10, "mean steps per episode <= 25 over 10 episodes")

# What of the task a run is told (claims.py: its claims on GWH14's numbers are variants). GWH14's
# MDP pays -1 per step; the shaped reward, the seed report's, tells the learner where the goal is.
MODEL_KNOWLEDGE = {"env.reward=shaped": "reward: the distance to the goal (its position)"}
SHAPED = MODEL_KNOWLEDGE["env.reward=shaped"]

# ------------------------------------------------------------ the reproduction (scripts/reproduce.py)
TITLE = "The square (GWH14's first experiment; the seed report's 4.1)"
# the README's paragraph on the domain: words, no numbers (those come from the data)
SUMMARY = ("DGPQ on GWH14's own reward (-1 per step, `paper`), on the seed report's shaped reward (which tells "
           "the learner where the goal is: a variant using the model) and with the seed report's own settings, "
           'an RBF against a manifold kernel, and a random walk on each reward as the trivial baseline.')
# (seeds, episodes) at each scale; an experiment may name its own as a third item
SCALES = {"smoke": (1, 3), "quick": (4, 15), "full": (10, 100), "report": (10, 100)}
NO_CAP = 20_000   # steps: 4x the seed report's 5,000, far past GWH14's ~100
# an experiment of this domain reproduced apart (its own --only name): the module holding its plan
APART = {"square-paper-tuned": "paper_tuned"}
REPRODUCE = [
    ("square-shaped", dict(agent="dgpq", preset="shaped")),
    ("square-report", dict(agent="dgpq", preset="report")),
    ("square-paper", dict(agent="dgpq", preset="paper")),
    ("square-shaped-exact", dict(agent="dgpq", preset="shaped", gp="exact")),
    ("square-shaped-manifold", dict(agent="dgpq", preset="shaped", gp="exact", kernel="manifold")),
    # the trivial baselines of the claims: a random walk on each reward
    ("square-random", dict(agent="random", preset="shaped")),
    ("square-random-paper", dict(agent="random", preset="paper")),
    # GWH14 and the seed report state no cap, and the first episodes pass 200 steps: their claims
    # are judged on runs capped far beyond what they claim (the seed report's only in episode 1)
    ("square-paper-nocap", dict(agent="dgpq", preset="paper", max_steps=NO_CAP)),
    ("square-report-nocap", dict(agent="dgpq", preset="report", max_steps=NO_CAP),
     {"smoke": (1, 1), "quick": (6, 1), "full": (10, 1), "report": (10, 1)}),
]


def episode_one(name: str):
    """The claim's measure: each seed's steps in episode 1, censored where a seed was cut by the cap
    before the goal (its true first episode is longer; a budget ends a seed only between episodes)."""
    def measure(runs):
        from trl_dgpq.analysis.claims import seeds_interval
        run = runs[name]
        first = run.df[run.df.episode == 1].set_index("seed")
        steps, cap = first["steps"], run.config["env"]["max_steps"]
        got = seeds_interval(steps)
        # a goal reached at the cap's step is no cut; without the column, an episode at the cap is one
        reached = first["terminated"].astype(bool) if "terminated" in first else steps < cap
        capped = int((~reached).sum())
        return replace(got, censored=f"{capped} of {len(steps)} seeds capped at {cap} steps") if capped else got
    return measure


def later_episodes(name: str, first: int = 3):
    """The claim's measure: each seed's median steps over its episodes ``first`` onwards; censored
    where a seed ran none of them (under an env-step budget its first episodes can take it all: its
    later ones are unknown, so the interval says nothing above its low end)."""
    def measure(runs):
        from trl_dgpq.analysis.claims import seeds_interval
        df = runs[name].df
        medians = df[df.episode >= first].groupby("seed")["steps"].median()
        missing = df.seed.nunique() - len(medians)
        if not len(medians):
            raise ValueError(f"{name}: no seed ran an episode {first} within the budget")
        got = seeds_interval(medians)
        return replace(got, censored=f"{missing} of {df.seed.nunique()} seeds ran no episode {first} within the "
                                     "budget") if missing else got
    return measure


def declared_claims() -> list:
    """The square's claims, fixed before any run: GWH14's on its own MDP (-1 per step, `paper`,
    with no cap near its numbers) and on the seed report's shaped reward (a variant: it tells the
    learner where the goal is), the seed report's on its own settings (episode 1 uncapped too)."""
    from trl_dgpq.analysis.claims import Agrees, Claim
    out = []
    for reward, name, base in (("GWH14's reward, -1 per step (`paper`), capped at 20,000 steps", "square-paper-nocap",
                                "square-random-paper"),
                               ("the seed report's shaped reward (`shaped`)", "square-shaped", "square-random")):
        key = name.removeprefix("square-").removesuffix("-nocap")
        out += [Claim(f"square/{key}/episode-1", "GWH14", f"DGPQ reaches the goal in ~100 steps in episode 1; "
                      f"run on {reward}", Agrees(100, 3, higher_is_better=False), episode_one(name), (name,)),
                Claim(f"square/{key}/episodes-3+", "GWH14", "~20 steps per episode (the optimum ~17) within 2-3 "
                      f"episodes: each seed's median from episode 3 on; run on {reward}",
                      Agrees(20, 1.5, higher_is_better=False), later_episodes(name), (name,), baseline=base)]
    out.append(Claim("square/report/episode-1", "the seed report", "its settings (exact GP, Section 5's values, "
                     "L_Q 9) take 1,000-5,000 steps in episode 1; run capped at 20,000 steps",
                     Agrees(math.sqrt(1000 * 5000), math.sqrt(5), higher_is_better=False),
                     episode_one("square-report-nocap"), ("square-report-nocap",), source_model=(SHAPED,)))
    return out


CLAIMS = declared_claims()


def reproduce_section(runs: dict, out: Path, label: str, title: str, judged: list) -> str:
    """REPORT.md's square section (seed report Figures 2-4); ``runs``: {name in REPRODUCE: Run};
    ``judged``: the verdicts of ``CLAIMS``."""
    from trl_dgpq.analysis.claims import seeds_interval
    from trl_dgpq.analysis.figures import episode_figures
    for folder in ("square", "square-kernels"):
        (out / folder).mkdir(exist_ok=True)
    presets = {"square-shaped": "shaped", "square-report": "report", "square-paper": "paper"}
    kernels = {"square-shaped-exact": "RBF (exact GP)", "square-shaped-manifold": "manifold (exact GP)"}
    for figure, names in (("square", presets), ("square-kernels", kernels)):   # each run labelled by its name
        shown = [n for n in names if n in runs]
        episode_figures([runs[n] for n in shown], [names[n] for n in shown], out / figure, title=title)
    from trl_dgpq.collectors.evaluate import job_folders
    shaped = runs.get("square-shaped")
    # rebuilt from published data (no checkpoint): drawn from what the run's figure showed, if kept
    qhat = qhat_figure(shaped.path if shaped is not None and job_folders(shaped.path) else None, out / "square", title)
    rows = ["| run | seeds x episodes | episode 1 steps: IQM [95 % CI] over seeds | episodes 3+: each seed's median "
            "steps, IQM [95 % CI] | last 5 episodes: each seed's mean steps, IQM [95 % CI] | capped episodes (share) "
            "| kernel fits per seed (mean) | ms per seed-step |", "|---|---|---|---|---|---|---|---|"]
    for name, run in runs.items():
        df = run.df
        E = int(df.episode.max())
        cell = lambda per_seed: seeds_interval(per_seed).text("{:.1f}") if len(per_seed) else "–"  # noqa: E731
        cells = [cell(df[df.episode == 1].set_index("seed")["steps"]),
                 cell(df[df.episode >= 3].groupby("seed")["steps"].median()),   # (a run of one episode has none)
                 cell(df[df.episode > E - 5].groupby("seed")["steps"].mean())]
        rows.append(f"| {name.removeprefix('square-')} | {df.seed.nunique()} x {E} | " + " | ".join(cells)
                    + f" | {(df.steps >= run.config['env']['max_steps']).mean():.0%} | {kernel_fits_per_seed(df):g} "
                    f"| {ms_per_seed_step(df):.2f} |")
    sentences = [j.bullet() for j in judged] + [
        "- RBF against the manifold kernel (Figure 4; exact GP, shaped): the rows shaped-exact and shaped-manifold. "
        "sigma_tol2 is reached after one sample, so the GPs hold a point or two and the kernel barely matters here.",
    ]
    return (f"## Square (seed report 4.1; GWH14's first experiment) -- Figures 2-4\n\n{label}\n\n"
            + "\n".join(rows) + "\n\n" + "\n".join(sentences)
            + "\n\n![steps](square/steps_per_episode.png) ![time](square/time_per_step.png) "
              "![kernels](square-kernels/steps_per_episode.png)"
            + (" ![Q̂](square/qhat.png)" if qhat else "") + "\n")


# ------------------------------------------------------------ what DGPQ learned (scripts/plot.py)
def qhat_grid(agent, n: int = 41, row: int = 0):
    """(xs, Q) with Q[i, j, a] = Q̂_a at the state (xs[j], xs[i]) of seed row ``row``."""
    import torch
    xs = torch.linspace(0.0, 1.0, n, dtype=torch.float64)
    q = torch.empty(n, n, agent.A, dtype=torch.float64)
    for i, y in enumerate(xs):
        for j, x in enumerate(xs):
            state = torch.tensor([[x, y]], dtype=torch.float64).expand(agent.S, 2)
            q[i, j] = agent.qhat(agent.features(state))[row]
    return xs.numpy(), q.numpy()


def greedy_path(env, agent, row: int = 0) -> np.ndarray:
    """Seed row ``row``'s positions over one evaluation episode, exploration off."""
    from trl_dgpq.collectors.evaluate import Frozen, episode_steps
    env.for_evaluation()
    td = env.reset()
    path = [td["observation"][row].numpy().copy()]
    path += [nxt["observation"][row].numpy().copy() for _, nxt, _ in episode_steps(env, Frozen(agent).act, td, row)]
    return np.array(path)


def qhat_drawn(folder: Path) -> Optional[dict]:
    """What qhat.png shows of the DGPQ run in ``folder`` (its last checkpoint), as plain data: Q̂ on
    a grid, each action's stored pairs, a greedy evaluation episode, the goal. None for an agent
    without Q̂ (or one that scales its states: positions are Q̂'s states as they are)."""
    from trl_dgpq.collectors.evaluate import jobs, restore
    config, env, agent, _ = restore(jobs(folder)[0])
    if not hasattr(agent, "qhat") or agent.scale is not None:
        return None
    xs, q = qhat_grid(agent)
    pairs = []
    for a in range(len(env.action_names)):
        valid = np.isfinite(agent.qhat.mu[0, a].numpy())
        pairs.append(agent.qhat.s[0, a].numpy()[valid].tolist())
    return dict(q=q.tolist(), names=list(env.action_names), pairs=pairs, path=greedy_path(env, agent).tolist(),
                goal=list(env.cfg.goal), radius=env.cfg.goal_radius, seed=config["run"]["seeds"][0], run=folder.name)


def qhat_figure(folder: Optional[Path], out: Path, title: str = "") -> Optional[Path]:
    """qhat.png: Q̂ of each action over the square for the first seed of the DGPQ run in
    ``folder`` (``qhat_drawn``), its stored pairs as dots, the goal, and one greedy evaluation
    episode; beside them the greedy value max_a Q̂ and the greedy action; what it draws is kept as
    qhat.json.xz. With ``folder`` None (a publication rebuilt from its data), drawn from that file.
    None for an agent without Q̂, or with neither."""
    import matplotlib.pyplot as plt

    from trl_dgpq.analysis.figures import load_drawn, save_drawn
    data = out / "qhat.json.xz"
    if folder is not None:
        drawn = qhat_drawn(folder)
        if drawn is None:
            return None
        save_drawn(data, drawn)
    got = load_drawn(data, fresh=folder is not None)
    if got is None:
        return None
    q, names, path = np.asarray(got["q"]), got["names"], np.asarray(got["path"])
    panels = len(names) + 2
    fig, axes = plt.subplots(1, panels, figsize=(3.1 * panels, 3.3), constrained_layout=True)
    lo, hi = float(np.nanmin(q)), float(np.nanmax(q))
    extent = (0, 1, 0, 1)
    for a, (ax, name) in enumerate(zip(axes, names)):
        im = ax.imshow(q[:, :, a], origin="lower", extent=extent, vmin=lo, vmax=hi, cmap="viridis")
        pts = np.asarray(got["pairs"][a]).reshape(-1, 2)
        ax.plot(pts[:, 0], pts[:, 1], ".", color="w", ms=2, alpha=0.7)
        ax.set_title(f"Q̂({name}): {len(pts)} pairs", fontsize=9)
    fig.colorbar(im, ax=axes[len(names) - 1], shrink=0.8)
    greedy = axes[-2].imshow(q.max(-1), origin="lower", extent=extent, cmap="viridis")
    axes[-2].set_title("greedy value max_a Q̂", fontsize=9)
    fig.colorbar(greedy, ax=axes[-2], shrink=0.8)
    cmap = plt.get_cmap("tab10", len(names))
    axes[-1].imshow(q.argmax(-1), origin="lower", extent=extent, cmap=cmap, vmin=-0.5, vmax=len(names) - 0.5)
    for a, name in enumerate(names):
        axes[-1].plot([], [], "s", color=cmap(a), label=name)
    axes[-1].legend(fontsize=7, loc="lower right")
    axes[-1].set_title("greedy action (ties: lowest index)", fontsize=9)
    for ax in axes:
        ax.add_patch(plt.Circle(got["goal"], got["radius"], fill=False, color="r", lw=1.2))
        ax.plot(path[:, 0], path[:, 1], "-", color="r", lw=1.0)
        ax.set_xlim(0, 1)
        ax.set_ylim(0, 1)
        ax.set_xlabel("x")
    axes[0].set_ylabel("y")
    fig.suptitle(f"{title + ': ' if title else ''}seed {got['seed']} after {got['run']}'s training; dots: Q̂'s pairs; "
                 f"red: the goal and a greedy evaluation episode ({len(path) - 1} steps)", fontsize=9)
    fig.savefig(out / "qhat.png", dpi=110)
    plt.close(fig)
    return out / "qhat.png"


def figures(runs, labels, out: Path, title: str = "", **_) -> list:
    """The generic episode figures, and qhat.png for the first DGPQ run with a checkpoint."""
    from trl_dgpq.analysis.figures import episode_figures
    from trl_dgpq.collectors.evaluate import job_folders
    written = episode_figures(runs, labels, out, title=title)
    for run in runs:
        if run.config and run.agent == "dgpq" and job_folders(run.path):
            path = qhat_figure(run.path, out, title)
            if path is not None:
                written.append(path)
            break
    return written
