"""What the analysis says about block pushing: steps per episode, success, the block's
final distance to the goal (seed report Figure 5)."""
from __future__ import annotations

from pathlib import Path

from trl_dgpq.analysis import Threshold, kernel_fits_per_seed, ms_per_seed_step

MEASURE = ("steps", "steps per episode")
TERMINATED = "the block reached the goal or fell off the table"
THRESHOLD = Threshold("success", ">=", 0.9, 10, "success in >= 90 % of 10 episodes")
DEFAULT_LAST = 20  # episodes at the end that the table uses


def figures(runs, labels, out: Path, last=None, title: str = "", **_) -> list:
    """push.png: the block's distance to the goal at each episode's end (the final reward is
    2 minus it; median and IQR over seeds) -- not the return, which is larger for a 50-step
    failure than a 10-step success -- above the success rate per episode; push.md: ``table``."""
    import matplotlib.pyplot as plt

    from trl_dgpq.analysis.figures import band_plot, save
    fig, (ax, sax) = plt.subplots(2, 1, figsize=(6.4, 6.4), sharex=True, height_ratios=(3, 2))
    for run, label in zip(runs, labels):
        df = run.df
        line = band_plot(ax, df, df["distance"], f"{label} ({df.seed.nunique()} seeds)")
        rate = df["success"].groupby(df["episode"]).mean()
        sax.plot(rate.index, rate, color=line.get_color(), lw=1.2)
    ax.set_ylabel("block's final distance to the goal (m)")
    ax.legend(title="median, shaded: inter-quartile range", fontsize=8, title_fontsize=8)
    sax.set_ylabel("success rate (share of seeds)")
    sax.set_xlabel("episode")
    sax.set_ylim(-0.03, 1.03)
    for a in (ax, sax):
        a.grid(alpha=0.3)
    if title:
        ax.set_title(title, fontsize=9)
    written = save(fig, out / "push.png")
    (out / "push.md").write_text(table(runs, labels, last or DEFAULT_LAST))
    return [written, out / "push.md"]


def table(runs, labels, last: int) -> str:
    """Markdown: over the last ``last`` episodes, success rate, mean steps of the successful
    episodes, fall-offs; the first successful episode (median over seeds), kernel fits."""
    lines = ["| run | seeds x episodes | success, last episodes | steps to goal (successes) | fell off "
             "| first success (median episode) | kernel fits per seed | ms per seed-step |",
             "|---|---|---|---|---|---|---|---|"]
    for run, label in zip(runs, labels):
        df = run.df
        tail = df[df["episode"] > df["episode"].max() - last]
        wins = tail[tail["success"]]
        first = df[df["success"]].groupby("seed")["episode"].min().reindex(df.seed.unique())
        steps = f"{wins.steps.mean():.1f}" if len(wins) else "–"
        median = first.fillna(float("inf")).median()            # a seed that never succeeded counts as last
        first_txt = ("never" if median == float("inf") else f"{median:g}") + (
            f" ({first.isna().sum()} never)" if first.isna().any() else "")
        lines.append(f"| {label} | {df.seed.nunique()} x {df.episode.max()} | {tail.success.mean():.1%} | {steps} "
                     f"| {tail.fell_off.mean():.1%} | {first_txt} | {kernel_fits_per_seed(df):g} "
                     f"| {ms_per_seed_step(df):.2f} |")
    return "\n".join(lines) + f"\n\nLast {last} episodes of each run; steps to goal: mean over its successful ones.\n"


# ------------------------------------------------------------ the reproduction (scripts/reproduce.py)
# (seeds, episodes) at each scale; an experiment may name its own as a third item
SCALES = {"smoke": (1, 3), "quick": (6, 60), "full": (10, 100), "report": (10, 100)}
REPRODUCE = [
    ("push-rbf", dict(agent="dgpq", preset="shaped")),
    ("push-manifold", dict(agent="dgpq", preset="manifold")),
    ("push-oracle", dict(agent="oracle")),
]


def reproduce_section(runs: dict, out: Path, label: str, title: str) -> str:
    """REPORT.md's push section; ``runs``: {name in REPRODUCE: Run}."""
    (out / "push").mkdir(exist_ok=True)
    figures(list(runs.values()), ["DGPQ RBF", "DGPQ manifold", "oracle"], out / "push", DEFAULT_LAST, title=title)
    rates = [r.df[r.df.episode > r.df.episode.max() - DEFAULT_LAST].success.mean() for r in runs.values()]
    sentence = (f"- Seed report: the goal was reached in three episodes, and performance was very spiky (its "
                f"code never stepped the robot; no numbers to compare). Ours: success over the last 20 episodes "
                f"{rates[0]:.0%} (RBF), {rates[1]:.0%} (manifold), {rates[2]:.0%} (oracle) -- "
                + ("DGPQ learns the task." if min(rates[:2]) >= 0.8 else "DGPQ does not learn it reliably at this "
                   "length.") + " GWH14 had no robot experiment.")
    return (f"## Block pushing (seed report 4.3) -- Figure 5\n\n{label}\n\n" + (out / "push" / "push.md").read_text()
            + "\n" + sentence + "\n\n![push](push/push.png)\n")
