"""Figures any run gets, and the drawing helpers the domains' figures share."""
from __future__ import annotations

import textwrap
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import matplotlib.ticker  # noqa: E402
from cycler import cycler  # noqa: E402

from .summary import band  # noqa: E402

# tab10's colours, then the same dashed, then dash-dotted: the report's liquidation panels draw 14
# runs, and matplotlib's default cycle gave the 11th the 1st one's look (ddpg-course = ac-optimal).
CYCLE = cycler(linestyle=["-", "--", "-."]) * cycler(color=plt.get_cmap("tab10").colors)
plt.rcParams["axes.prop_cycle"] = CYCLE

FIGURES = {
    "steps_per_episode.png": ("steps per episode", lambda df: df["steps"]),
    # wall time, as the console reports it (CPU time counts every thread: ~2x wall with 2)
    "time_per_step.png": ("wall time per step (ms, per seed)", lambda df: df["wall_s"] / df["steps"] * 1e3),
}


def fit_titles(fig) -> None:
    """Wrap the figure's title and each axes' title, at spaces, until each is no wider than
    the figure (its title) or its axes (a panel's): a long one was cut at the image's edges."""
    renderer = fig.canvas.get_renderer()
    texts = [(fig._suptitle, fig.bbox.width - 8)] if fig._suptitle is not None else []
    texts += [(ax.title, ax.bbox.width) for ax in fig.axes if ax.get_title()]
    for text, width in texts:
        lines = text.get_text().split("\n")
        n = max(map(len, lines))
        while n > 12 and text.get_window_extent(renderer).width > width:
            n = int(n * 0.9)
            text.set_text("\n".join(textwrap.fill(line, n, break_long_words=False) for line in lines))


def save_drawn(path: Path, data: dict) -> Path:
    """What a figure drawn from a checkpoint shows, as plain data beside it (``<figure>.json.xz``):
    checkpoints are not published, so a rebuild draws the figure again from this."""
    import json
    import lzma
    with lzma.open(path, "wt") as f:
        json.dump(data, f, separators=(",", ":"))
    return path


def load_drawn(path: Path, fresh: bool = False):
    """``save_drawn``'s data, or None where there is none. Unless just written (``fresh``), only a
    publication's (its figure folders sit beside its data/): anywhere else a file left by an earlier
    drawing could be another run's."""
    import json
    import lzma

    from .published import is_published
    if not Path(path).is_file() or not (fresh or is_published(Path(path).parent.parent)):
        return None
    with lzma.open(path, "rt") as f:
        return json.load(f)


def save(fig, path: Path, title: str = "") -> Path:
    if title:
        fig.suptitle(title, fontsize=9)
    for _ in range(2):  # wrapping changes the titles' height, the layout the axes' width
        fit_titles(fig)
        if fig.get_layout_engine() is None:
            fig.tight_layout()
        else:
            fig.canvas.draw()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


# Candidate ticks of a log axis, as mantissas of each decade: the sparsest set that puts at least
# three labels on the axis is used (a fixed 1-2-5 set labelled a narrow axis, 17-40 steps or
# $200k-$600k, once or twice).
MANTISSAS = ((1, 2, 5), (1, 2, 3, 5), (1, 1.5, 2, 3, 4, 5, 6, 8), (1, 1.2, 1.5, 2, 2.5, 3, 4, 5, 6, 7, 8, 9),
             tuple(1 + k / 20 for k in range(180)))


class LogTicks(matplotlib.ticker.Locator):
    """Major ticks of a log axis: at least ``least`` of them inside the view where the view
    allows (whole numbers only, with ``integer``)."""

    def __init__(self, least: int = 3, integer: bool = False):
        self.least, self.integer = least, integer

    def __call__(self):
        return self.tick_values(*self.axis.get_view_interval())

    def tick_values(self, vmin, vmax):
        import math
        lo, hi = sorted((vmin, vmax))
        if not hi > 0:
            return []
        lo = max(lo, hi * 1e-12)
        ticks = []
        for mantissas in MANTISSAS:
            ticks = [m * 10.0 ** e for e in range(math.floor(math.log10(lo)), math.ceil(math.log10(hi)) + 1)
                     for m in mantissas]
            ticks = [t for t in ticks if lo <= t <= hi and (not self.integer or float(t).is_integer())]
            if len(ticks) >= self.least:
                break
        return ticks


def plain(value, _=None) -> str:
    return f"{value:g}"


def dollars(value, _=None) -> str:
    """$350k, $1.2M: a cost axis's labels."""
    for scale, unit in ((1e9, "B"), (1e6, "M"), (1e3, "k")):
        if abs(value) >= scale:
            return f"${value / scale:.3g}{unit}".replace("$-", "-$")
    return f"${value:.3g}".replace("$-", "-$")


def log_axis(ax, formatter=plain, integer: bool = False, axis: str = "y") -> None:
    """A log axis with at least three labelled ticks (``LogTicks``), labelled by ``formatter``."""
    which = getattr(ax, f"{axis}axis")
    getattr(ax, f"set_{axis}scale")("log")
    which.set_major_locator(LogTicks(integer=integer))
    which.set_major_formatter(matplotlib.ticker.FuncFormatter(formatter))
    which.set_minor_formatter(matplotlib.ticker.NullFormatter())


def log_steps_axis(ax) -> None:
    log_axis(ax, integer=True)


def line_style(k: int) -> dict:
    """The k-th run's colour and line style, for a run drawn in several axes (each axes starts
    its own cycle, so the k-th line of one need not be the k-th run)."""
    styles = list(CYCLE)
    return styles[k % len(styles)]


def episode_axis(ax) -> None:
    """Whole episodes on the x axis: a short run was ticked at 2.5, 7.5."""
    ax.xaxis.set_major_locator(matplotlib.ticker.MaxNLocator(integer=True, steps=[1, 2, 5, 10]))


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
        episode_axis(ax)
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
    found = [(label, df) for label, df in found if column in df]  # (an evaluation from before the column)
    if not found:
        return None
    fig, ax = plt.subplots(figsize=(max(4.0, 1.2 + 1.3 * len(found)), 4.0))
    values = [df[column] for _, df in found]
    ax.boxplot(values, showmeans=True)
    lo, hi = min(v.min() for v in values), max(v.max() for v in values)
    if lo > 0 and hi >= 5 * min(v.median() for v in values):
        # one capped episode (200 steps beside a box at 17-20) squashed the boxes on a linear axis
        log_axis(ax, integer=column == "steps")
        ylabel += " (log scale)"
    ax.set_xticks(range(1, len(found) + 1), [f"{label}\n({df.seed.nunique()} seeds x {df.episode.max()})"
                                             for label, df in found], fontsize=7)
    ax.set_ylabel(ylabel)
    ax.set_title("evaluation, exploration off\n(box: quartiles; triangle: mean)", fontsize=9)
    ax.grid(alpha=0.3, axis="y")
    return save(fig, out / "eval_returns.png")
