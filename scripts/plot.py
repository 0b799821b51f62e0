#!/usr/bin/env python
"""Figures of a run (or of several runs, overlaid), from OUT/episodes.csv.

    python scripts/plot.py runs/square-shaped
    python scripts/plot.py                      # the newest folder under runs/
    python scripts/plot.py runs/a runs/b --labels rbf manifold --out cmp/

Writes into the (first) run folder, or --out:
    steps_per_episode.png   steps to goal per episode (seed report Fig. 2)
    time_per_step.png       CPU time per step per episode (seed report Fig. 3)
Each curve is the median across seeds with the inter-quartile band.
"""
from __future__ import annotations

import argparse
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


def plot_runs(runs, labels, out: Path, logy_steps: bool = True) -> list:
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
        fig.tight_layout()
        path = out / fname
        fig.savefig(path, dpi=120)
        plt.close(fig)
        written.append(path)
    return written


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("runs", nargs="*", help="run folders holding episodes.csv (default: newest under runs/)")
    p.add_argument("--labels", nargs="+", default=None)
    p.add_argument("--out", default=None, help="folder for the PNGs (default: the first run folder)")
    p.add_argument("--linear", action="store_true", help="linear y axis for steps")
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
    for path in plot_runs(args.runs, labels, out, logy_steps=not args.linear):
        print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
