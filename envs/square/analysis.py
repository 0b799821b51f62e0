"""What the analysis says about the square: steps per episode, and a threshold near the optimum (~17)."""
from __future__ import annotations

from pathlib import Path
from typing import Optional

import numpy as np

from trl_dgpq.analysis import Threshold, kernel_fits_per_seed, median_steps, ms_per_seed_step


MEASURE = ("steps", "steps per episode")
MEASURE_LOWER_IS_BETTER = True  # the at-budget scores (report: IQM, P(improvement), profiles) are negated
TERMINATED = "reached the goal"
THRESHOLD = Threshold("steps", "<=", 25, 10, "mean steps per episode <= 25 over 10 episodes")

# ------------------------------------------------------------ the reproduction (scripts/reproduce.py)
# (seeds, episodes) at each scale; an experiment may name its own as a third item
SCALES = {"smoke": (1, 3), "quick": (6, 50), "full": (10, 100), "report": (10, 100)}
REPRODUCE = [
    ("square-shaped", dict(agent="dgpq", preset="shaped")),
    ("square-report", dict(agent="dgpq", preset="report")),
    ("square-paper", dict(agent="dgpq", preset="paper")),
    ("square-shaped-exact", dict(agent="dgpq", preset="shaped", gp="exact")),
    ("square-shaped-manifold", dict(agent="dgpq", preset="shaped", gp="exact", kernel="manifold")),
]


def claims(runs: dict) -> list:
    """GWH14's and the seed report's numbers on the square against ours (median over seeds)."""
    from trl_dgpq.analysis.claims import Claim, within
    out = []
    if "square-shaped" in runs:
        df = runs["square-shaped"].df
        first, later = median_steps(df, [1]), median_steps(df, range(3, int(df.episode.max()) + 1))
        out += [Claim("GWH14", "DGPQ reaches the goal in ~100 steps in episode 1", f"{first:g} (`shaped`; agreeing if within 3x)",
                      within(first, 100, 3)),
                Claim("GWH14", "~20 steps per episode (optimum ~17) within 2-3 episodes",
                      f"{later:g} from episode 3 on", within(later, 20, 1.5))]
    if "square-report" in runs:
        run = runs["square-report"]
        first, cap = median_steps(run.df, [1]), run.config["env"]["max_steps"]
        out.append(Claim("seed report", "its settings (exact GP, Section 5 values, L_Q 9) take 1,000-5,000 steps "
                         "in episode 1", f"{first:g} with the `report` preset, episodes capped at {cap}",
                         "partly" if first >= cap else "not reproduced"))
    return out


def reproduce_section(runs: dict, out: Path, label: str, title: str) -> str:
    """REPORT.md's square section (seed report Figures 2-4); ``runs``: {name in REPRODUCE: Run}."""
    from trl_dgpq.analysis.figures import episode_figures
    for folder in ("square", "square-kernels"):
        (out / folder).mkdir(exist_ok=True)
    named = list(runs.values())
    episode_figures(named[:3], ["shaped", "report", "paper"], out / "square", title=title)
    episode_figures(named[3:], ["RBF (exact GP)", "manifold (exact GP)"], out / "square-kernels", title=title)
    qhat = qhat_figure(runs["square-shaped"].path, out / "square", title) if "square-shaped" in runs else None
    rows = ["| preset | seeds x episodes | episode 1 steps (median) | episodes 3+ (median) | last 5 (median) "
            "| capped episodes | kernel fits / seed | ms per seed-step |", "|---|---|---|---|---|---|---|---|"]
    facts = {}
    for name, run in runs.items():
        df = run.df
        E = int(df.episode.max())
        first, later, last = (median_steps(df, [1]), median_steps(df, range(3, E + 1)),
                              median_steps(df, range(E - 4, E + 1)))
        facts[name] = (first, later)
        rows.append(f"| {name.removeprefix('square-')} | {df.seed.nunique()} x {E} | {first:g} | {later:g} | {last:g} "
                    f"| {(df.steps >= run.config['env']['max_steps']).mean():.0%} | {kernel_fits_per_seed(df):g} "
                    f"| {ms_per_seed_step(df):.2f} |")
    kf, kl = facts["square-shaped-manifold"]
    ef, el = facts["square-shaped-exact"]
    sentences = [c.bullet() for c in claims(runs)] + [
        f"- RBF vs manifold kernel (Figure 4; exact GP, shaped): episode 1 {ef:g} vs {kf:g}, episodes 3+ {el:g} vs "
        f"{kl:g}: {'the same' if (ef, el) == (kf, kl) else 'close'} -- sigma_tol2 is reached after one sample, so "
        "the GPs hold a point or two and the kernel barely matters here.",
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


def qhat_figure(folder: Path, out: Path, title: str = "") -> Optional[Path]:
    """qhat.png: Q̂ of each action over the square for the first seed of the DGPQ run in
    ``folder`` (its last checkpoint), its stored pairs as dots, the goal, and one greedy
    evaluation episode; beside them the greedy value max_a Q̂ and the greedy action.
    None for an agent without Q̂."""
    import matplotlib.pyplot as plt

    from trl_dgpq.analysis.figures import save
    from trl_dgpq.collectors.evaluate import jobs, restore
    config, env, agent, _ = restore(jobs(folder)[0])
    if not hasattr(agent, "qhat") or agent.scale is not None:  # positions are Q̂'s states as they are
        return None
    xs, q = qhat_grid(agent)
    names = env.action_names
    seed = config["run"]["seeds"][0]
    path = greedy_path(env, agent)
    goal, radius = env.cfg.goal, env.cfg.goal_radius
    panels = len(names) + 2
    fig, axes = plt.subplots(1, panels, figsize=(3.1 * panels, 3.3), constrained_layout=True)
    lo, hi = float(np.nanmin(q)), float(np.nanmax(q))
    extent = (0, 1, 0, 1)
    for a, (ax, name) in enumerate(zip(axes, names)):
        im = ax.imshow(q[:, :, a], origin="lower", extent=extent, vmin=lo, vmax=hi, cmap="viridis")
        valid = np.isfinite(agent.qhat.mu[0, a].numpy())
        pts = agent.qhat.s[0, a].numpy()[valid]
        ax.plot(pts[:, 0], pts[:, 1], ".", color="w", ms=2, alpha=0.7)
        ax.set_title(f"Q̂({name}): {valid.sum()} pairs", fontsize=9)
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
        ax.add_patch(plt.Circle(goal, radius, fill=False, color="r", lw=1.2))
        ax.plot(path[:, 0], path[:, 1], "-", color="r", lw=1.0)
        ax.set_xlim(0, 1)
        ax.set_ylim(0, 1)
        ax.set_xlabel("x")
    axes[0].set_ylabel("y")
    fig.suptitle(f"{title + ': ' if title else ''}seed {seed} after {folder.name}'s training; dots: Q̂'s pairs; "
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
