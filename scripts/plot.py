#!/usr/bin/env python
"""Figures of a run (or of several runs, overlaid), from OUT/episodes.csv.

    python scripts/plot.py runs/square-shaped
    python scripts/plot.py                      # the newest folder under runs/
    python scripts/plot.py runs/a runs/b --labels rbf manifold --out cmp/

Writes into the (first) run folder, or --out:
    steps_per_episode.png   steps to goal per episode (seed report Fig. 2)
    time_per_step.png       CPU time per step per episode (seed report Fig. 3)
Each curve is the median across seeds with the inter-quartile band.

Liquidation runs (all runs of a comparison, e.g. runs/liq/*) instead give
    liquidation_cost.png    mean implementation shortfall and mean ac_cost per block of
                            episodes (seed report Fig. 6), one panel per discount gamma,
                            the AC optimum's E* and U* as reference lines
    liquidation_time.png    wall time per episode per seed (seed report Fig. 7)
    comparison.md           over the last --last episodes of each run: mean ac_cost and
                            shortfall, and their ratio to an ac-optimal run of the
                            comparison on the same (seed, episode) price paths

Block-pushing runs (all runs of a comparison, e.g. runs/push/*) instead give
    push.png                the block's distance to the goal at each episode's end (the final
                            reward is 2 minus it; median and inter-quartile band over seeds;
                            seed report Fig. 5 -- not the return, which is larger for a
                            50-step failure than a 10-step success) above the success rate per episode (share
                            of seeds whose block reached the goal), all runs on one axis
    push.md                 over the last --last episodes (default 20): success rate,
                            mean steps of the successful episodes, fall-offs, the first
                            successful episode (median over seeds), kernel fits
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import matplotlib.ticker  # noqa: E402
import pandas as pd  # noqa: E402

FIGURES = {
    "steps_per_episode.png": ("steps", "steps per episode", lambda df: df["steps"]),
    "time_per_step.png": ("cpu_ms_per_step", "CPU time per step (ms, per seed)",
                          lambda df: df["cpu_s"] / df["steps"] * 1e3),
}


def band(df: pd.DataFrame, values: pd.Series) -> pd.DataFrame:
    """Median and quartiles across seeds, per episode."""
    g = values.groupby(df["episode"])
    return pd.DataFrame({"median": g.median(), "q25": g.quantile(0.25), "q75": g.quantile(0.75)})


def plot_runs(runs, labels, out: Path, logy_steps: bool = True, title: str = "") -> list:
    frames = [pd.read_csv(Path(r) / "episodes.csv") for r in runs]
    written = []
    for fname, (_, ylabel, value) in FIGURES.items():
        fig, ax = plt.subplots(figsize=(6.4, 4.0))
        for df, label in zip(frames, labels):
            b = band(df, value(df))
            line, = ax.plot(b.index, b["median"], label=f"{label} (median, {df.seed.nunique()} seeds)")
            ax.fill_between(b.index, b["q25"], b["q75"], color=line.get_color(), alpha=0.25, lw=0)
        ax.set_xlabel("episode")
        ax.set_ylabel(ylabel)
        if fname.startswith("steps") and logy_steps:
            ax.set_yscale("log")
            ax.yaxis.set_major_locator(matplotlib.ticker.FixedLocator([5, 10, 15, 20, 30, 50, 100, 200, 500]))
            ax.yaxis.set_major_formatter(matplotlib.ticker.ScalarFormatter())
            ax.yaxis.set_minor_formatter(matplotlib.ticker.NullFormatter())
        ax.grid(alpha=0.3, which="both")
        ax.legend(title="shaded: inter-quartile range", fontsize=8, title_fontsize=8, loc="best")
        if title:
            ax.set_title(title, fontsize=9)
        fig.tight_layout()
        path = out / fname
        fig.savefig(path, dpi=120)
        plt.close(fig)
        written.append(path)
    return written


def run_info(run) -> dict:
    """label parts of a run from its config.json: agent, preset, gamma (None for schedules)."""
    cfg = json.loads((Path(run) / "config.json").read_text())
    return dict(env=cfg["run"]["env"], agent=cfg["run"]["agent"], preset=cfg["run"]["preset"],
                gamma=cfg["agent"].get("gamma"), env_cfg=cfg["env"])


def liquidation_figures(runs, infos, labels, out: Path, block: int, last: int, title: str = "") -> list:
    from trl_dgpq.almgren_chriss import ACModel
    from trl_dgpq.envs import LiquidationConfig
    from trl_dgpq.config import from_dict
    frames = [pd.read_csv(Path(r) / "episodes.csv") for r in runs]
    model = ACModel.from_config(from_dict(LiquidationConfig, infos[0]["env_cfg"]))
    gammas = sorted({i["gamma"] for i in infos if i["gamma"] is not None}) or [None]
    written = []
    panels = [("implementation_shortfall", "mean implementation shortfall ($)", model.expected_shortfall(), "E*"),
              ("ac_cost", "mean ac_cost = shortfall + risk term ($)", model.utility(), "U*")]
    fig, axes = plt.subplots(2, len(gammas), figsize=(5.2 * len(gammas), 7.0), squeeze=False, sharex=True)
    tfig, taxes = plt.subplots(1, len(gammas), figsize=(5.2 * len(gammas), 3.6), squeeze=False)
    for j, gamma in enumerate(gammas):
        for df, label, info in zip(frames, labels, infos):
            if info["gamma"] not in (None, gamma):
                continue
            blk = (df["episode"] - 1) // block
            x = (blk.groupby(blk).first() + 1) * block
            for row, (col, ylabel, ref, name) in enumerate(panels):
                axes[row, j].plot(x, df[col].groupby(blk).mean(), label=label, lw=1.2)
            taxes[0, j].plot(x, df["wall_s"].groupby(blk).mean() * 1e3, label=label, lw=1.2)
        for row, (col, ylabel, ref, name) in enumerate(panels):
            ax = axes[row, j]
            ax.axhline(ref, color="k", ls="--", lw=1, label=f"AC optimum {name} = ${ref:,.0f}")
            ax.set_yscale("log")
            ax.set_ylabel(ylabel)
            ax.grid(alpha=0.3, which="both")
            ax.set_title(f"gamma = {gamma}" if gamma is not None else "")
        axes[1, j].set_xlabel(f"episode (mean of each block of {block})")
        axes[0, j].legend(fontsize=7)
        taxes[0, j].set_title(f"gamma = {gamma}" if gamma is not None else "")
        taxes[0, j].set_xlabel("episode")
        taxes[0, j].set_ylabel("wall ms per episode, per seed")
        taxes[0, j].set_yscale("log")
        taxes[0, j].grid(alpha=0.3, which="both")
        taxes[0, j].legend(fontsize=7)
    for f, name in ((fig, "liquidation_cost.png"), (tfig, "liquidation_time.png")):
        if title:
            f.suptitle(title, fontsize=9)
        f.tight_layout()
        f.savefig(out / name, dpi=120)
        plt.close(f)
        written.append(out / name)
    path = out / "comparison.md"
    path.write_text(comparison_table(frames, labels, infos, last))
    written.append(path)
    return written


def paired_ratios(df: pd.DataFrame, ref: pd.DataFrame, columns):
    """Mean of each column over the (seed, episode) pairs ``df`` shares with ``ref``, divided by
    ``ref``'s mean over the same pairs (same price paths); None if they share none."""
    pairs = df.merge(ref, on=["seed", "episode"], suffixes=("", "_ref"))
    return [pairs[c].mean() / pairs[c + "_ref"].mean() for c in columns] if len(pairs) else None


def comparison_table(frames, labels, infos, last: int) -> str:
    """Markdown: the last ``last`` episodes of each run, costs as ratios to the ac-optimal run
    on the same (seed, episode) pairs (common random numbers make the pairs comparable)."""
    ref = next((df for df, i in zip(frames, infos) if i["agent"] == "ac-optimal"), None)
    lines = ["| run | gamma | seeds x episodes | mean ac_cost ($) | ac_cost / optimum | mean shortfall ($) "
             "| shortfall / optimum | s per episode per seed |", "|---|---|---|---|---|---|---|---|"]
    for df, label, info in zip(frames, labels, infos):
        tail = df[df["episode"] > df["episode"].max() - last]
        ratios = ["–", "–"]
        if ref is not None:
            found = paired_ratios(tail, ref, ("ac_cost", "implementation_shortfall"))
            ratios = ratios if found is None else [f"{r:.3f}" for r in found]
        gamma = "–" if info["gamma"] is None else f"{info['gamma']:g}"
        lines.append(f"| {label} | {gamma} | {df.seed.nunique()} x {df.episode.max()} | {tail.ac_cost.mean():,.0f} "
                     f"| {ratios[0]} | {tail.implementation_shortfall.mean():,.0f} | {ratios[1]} "
                     f"| {df.wall_s.mean():.3g} |")
    note = (f"\nLast {last} episodes of each run. Ratios: mean over the (seed, episode) pairs the run shares "
            "with the ac-optimal run, divided by ac-optimal's mean over the same pairs (same price paths).\n")
    return "\n".join(lines) + "\n" + note


def push_figures(runs, labels, out: Path, last: int, title: str = "") -> list:
    frames = [pd.read_csv(Path(r) / "episodes.csv") for r in runs]
    fig, (ax, sax) = plt.subplots(2, 1, figsize=(6.4, 6.4), sharex=True, height_ratios=(3, 2))
    for df, label in zip(frames, labels):
        b = band(df, df["distance"])
        line, = ax.plot(b.index, b["median"], label=f"{label} ({df.seed.nunique()} seeds)", lw=1.2)
        ax.fill_between(b.index, b["q25"], b["q75"], color=line.get_color(), alpha=0.25, lw=0)
        sax.plot(b.index, df["success"].groupby(df["episode"]).mean(), color=line.get_color(), lw=1.2)
    # Not the return: 2 - distance is earned on every step, so a 50-step failure returns more
    # than a 10-step success. The final reward is 2 - this distance (2 within the goal radius).
    ax.set_ylabel("block's final distance to the goal (m)")
    ax.legend(title="median, shaded: inter-quartile range", fontsize=8, title_fontsize=8)
    sax.set_ylabel("success rate (share of seeds)")
    sax.set_xlabel("episode")
    sax.set_ylim(-0.03, 1.03)
    for a in (ax, sax):
        a.grid(alpha=0.3)
    if title:
        ax.set_title(title, fontsize=9)
    fig.tight_layout()
    fig.savefig(out / "push.png", dpi=120)
    plt.close(fig)
    (out / "push.md").write_text(push_table(frames, labels, last))
    return [out / "push.png", out / "push.md"]


def push_table(frames, labels, last: int) -> str:
    lines = ["| run | seeds x episodes | success, last episodes | steps to goal (successes) | fell off "
             "| first success (median episode) | kernel fits per seed | ms per seed-step |",
             "|---|---|---|---|---|---|---|---|"]
    for df, label in zip(frames, labels):
        tail = df[df["episode"] > df["episode"].max() - last]
        wins = tail[tail["success"]]
        first = df[df["success"]].groupby("seed")["episode"].min().reindex(df.seed.unique())
        fits = df.groupby("seed")["kernel_fits"].max().mean() if "kernel_fits" in df else 0
        steps = f"{wins.steps.mean():.1f}" if len(wins) else "–"
        median = first.fillna(float("inf")).median()            # a seed that never succeeded counts as last
        first_txt = ("never" if median == float("inf") else f"{median:g}") + (
            f" ({first.isna().sum()} never)" if first.isna().any() else "")
        lines.append(f"| {label} | {df.seed.nunique()} x {df.episode.max()} | {tail.success.mean():.1%} | {steps} "
                     f"| {tail.fell_off.mean():.1%} | {first_txt} | {fits:g} "
                     f"| {df.wall_s.sum() / df.steps.sum() * 1e3:.2f} |")
    return "\n".join(lines) + f"\n\nLast {last} episodes of each run; steps to goal: mean over its successful ones.\n"


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("runs", nargs="*", help="run folders holding episodes.csv (default: newest under runs/)")
    p.add_argument("--labels", nargs="+", default=None)
    p.add_argument("--out", default=None, help="folder for the PNGs (default: the first run folder)")
    p.add_argument("--linear", action="store_true", help="linear y axis for steps")
    p.add_argument("--block", type=int, default=100, help="liquidation: episodes per plotted mean")
    p.add_argument("--last", type=int, default=None,
                   help="episodes at the end that the table uses (liquidation: 1000, push: 20)")
    args = p.parse_args(argv)
    if not args.runs:
        found = sorted(Path("runs").glob("*/episodes.csv"), key=lambda f: f.stat().st_mtime)
        if not found:
            p.error("no run folder given and none found under runs/")
        args.runs = [str(found[-1].parent)]
    for r in args.runs:
        if not (Path(r) / "episodes.csv").is_file():
            p.error(f"{r}/episodes.csv not found (run scripts/train.py --out {r} first)")
    labels = args.labels or [Path(r).name for r in args.runs]
    if len(labels) != len(args.runs):
        p.error("give one label per run")
    out = Path(args.out or args.runs[0])
    out.mkdir(parents=True, exist_ok=True)
    infos = [run_info(r) if (Path(r) / "config.json").is_file() else None for r in args.runs]
    envs = {i["env"] if i is not None else None for i in infos}
    if envs == {"liquidation"}:
        written = liquidation_figures(args.runs, infos, labels, out, args.block, args.last or 1000)
    elif envs == {"push"}:
        written = push_figures(args.runs, labels, out, args.last or 20)
    else:
        written = plot_runs(args.runs, labels, out, logy_steps=not args.linear)
    for path in written:
        print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
