"""Figures any run gets, and the drawing helpers the domains' figures share."""
from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import matplotlib.ticker  # noqa: E402

from .summary import band  # noqa: E402

FIGURES = {
    "steps_per_episode.png": ("steps per episode", lambda df: df["steps"]),
    # wall time, as the console reports it (CPU time counts every thread: ~2x wall with 2)
    "time_per_step.png": ("wall time per step (ms, per seed)", lambda df: df["wall_s"] / df["steps"] * 1e3),
}


def save(fig, path: Path, title: str = "") -> Path:
    if title:
        fig.suptitle(title, fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def log_steps_axis(ax) -> None:
    ax.set_yscale("log")
    ax.yaxis.set_major_locator(matplotlib.ticker.FixedLocator([1, 2, 5, 10, 15, 20, 30, 50, 100, 200, 500, 1000, 2000,
                                                               5000, 10000]))
    ax.yaxis.set_major_formatter(matplotlib.ticker.ScalarFormatter())
    ax.yaxis.set_minor_formatter(matplotlib.ticker.NullFormatter())


def band_plot(ax, df, values, label: str):
    """Median across seeds per episode, with the inter-quartile band; returns the line."""
    b = band(df, values)
    line, = ax.plot(b.index, b["median"], label=label, lw=1.2)
    ax.fill_between(b.index, b["q25"], b["q75"], color=line.get_color(), alpha=0.25, lw=0)
    return line


def episode_figures(runs, labels, out: Path, logy_steps: bool = True, title: str = "") -> list:
    """steps_per_episode.png and time_per_step.png: median and IQR across seeds per episode."""
    written = []
    for fname, (ylabel, value) in FIGURES.items():
        fig, ax = plt.subplots(figsize=(6.4, 4.0))
        for run, label in zip(runs, labels):
            band_plot(ax, run.df, value(run.df), f"{label} (median, {run.df.seed.nunique()} seeds)")
        ax.set_xlabel("episode")
        log = fname.startswith("steps") and logy_steps
        ax.set_ylabel(ylabel + (" (log scale)" if log else ""))
        if log:
            log_steps_axis(ax)
        ax.grid(alpha=0.3, which="both")
        ax.legend(title="shaded: inter-quartile range", fontsize=8, title_fontsize=8, loc="best")
        ax.set_title(f"{ylabel}: median over seeds" + (f" ({title})" if title else ""), fontsize=9)
        written.append(save(fig, out / fname))
    return written


def evaluation_figure(runs, labels, out: Path, column: str, ylabel: str):
    """eval_returns.png: the distribution of ``column`` over every (seed, evaluation episode)
    of each run that has an eval.csv (``evaluate``); None if none has."""
    import pandas as pd
    found = [(label, pd.read_csv(run.path / "eval.csv")) for run, label in zip(runs, labels)
             if (run.path / "eval.csv").is_file()]
    if not found:
        return None
    fig, ax = plt.subplots(figsize=(max(4.0, 1.2 + 1.3 * len(found)), 4.0))
    ax.boxplot([df[column] for _, df in found], showmeans=True)
    ax.set_xticks(range(1, len(found) + 1), [f"{label}\n({df.seed.nunique()} seeds x {df.episode.max()})"
                                             for label, df in found], fontsize=7)
    ax.set_ylabel(ylabel)
    ax.set_title("evaluation, exploration off\n(box: quartiles; triangle: mean)", fontsize=9)
    ax.grid(alpha=0.3, axis="y")
    return save(fig, out / "eval_returns.png")
