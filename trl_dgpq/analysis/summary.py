"""Per-seed summaries, thresholds and pairing: one definition each."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd


@dataclass(frozen=True)
class Threshold:
    """A learner has met it when the mean of ``column`` over its last ``window`` episodes
    compares to ``value`` by ``op`` ("<=" or ">=")."""
    column: str
    op: str
    value: float
    window: int
    text: str

    def met(self, mean: pd.Series) -> pd.Series:
        return mean <= self.value if self.op == "<=" else mean >= self.value


def ms_per_seed_step(df: pd.DataFrame) -> float:
    """Wall milliseconds per step of one seed (a batch's time shared among its seeds)."""
    return float(df["wall_s"].sum() / df["steps"].sum() * 1e3)


def kernel_fits_per_seed(df: pd.DataFrame) -> float:
    """Mean over seeds of the kernel fits each made (the counter's last value; 0 if none)."""
    return float(df.groupby("seed")["kernel_fits"].max().mean()) if "kernel_fits" in df else 0.0


def band(df: pd.DataFrame, values: pd.Series) -> pd.DataFrame:
    """Median and quartiles across seeds, per episode."""
    g = values.groupby(df["episode"])
    return pd.DataFrame({"median": g.median(), "q25": g.quantile(0.25), "q75": g.quantile(0.75)})


def median_steps(df: pd.DataFrame, episodes) -> float:
    """Median over ``episodes`` of the median steps across seeds."""
    return float(df[df["episode"].isin(episodes)].groupby("episode")["steps"].median().median())


def rolling(df: pd.DataFrame, column: str, window: int, full: bool = False) -> pd.Series:
    """Each seed's mean of ``column`` over its last ``window`` episodes (``full``: only once
    it has that many)."""
    values = df[column].astype(float)
    return values.groupby(df["seed"]).transform(
        lambda v: v.rolling(window, min_periods=window if full else 1).mean())


def steps_to_threshold(df: pd.DataFrame, threshold: Threshold, budget=None) -> pd.Series:
    """Per seed: env steps when the mean over the threshold's window of episodes first met
    it, within ``budget`` if given (NaN: never). ``df`` as ``load_run`` gives it."""
    mean = rolling(df, threshold.column, threshold.window, full=True)
    met = threshold.met(mean) & (df["env_steps"] <= (budget or np.inf))
    first = df[met].groupby("seed")["env_steps"].first()
    return first.reindex(sorted(df["seed"].unique()))


def last_episodes(df: pd.DataFrame, window: int, budget=None) -> pd.DataFrame:
    """The window of results.csv and of every at-budget column: each seed's last ``window`` episodes
    that ended within ``budget`` env steps (None or 0: every episode it ran); a domain's own tables
    name theirs in their headers. ``df`` as ``load_run`` gives it."""
    within = df[df["env_steps"] <= budget] if budget else df
    return within.sort_values(["seed", "episode"], kind="stable").groupby("seed").tail(window)


def at_budget(df: pd.DataFrame, column: str, budget: int, window: int) -> pd.Series:
    """Per seed: mean of ``column`` over ``last_episodes`` (NaN for a seed none of whose episodes
    ended within ``budget``)."""
    means = last_episodes(df, window, budget).groupby("seed")[column].mean()
    return means.reindex(sorted(df["seed"].unique()))


def seed_means(df: pd.DataFrame, column: str, first: int = 1, last=None) -> pd.Series:
    """Per seed: the mean of ``column`` over its episodes ``first``..``last`` (None: to its end);
    NaN for a seed with none there."""
    window = df[(df["episode"] >= first) & (df["episode"] <= (last if last is not None else np.inf))]
    return window.groupby("seed")[column].mean().reindex(sorted(df["seed"].unique()))


def curve(df: pd.DataFrame, column: str, window: int, grid: np.ndarray) -> np.ndarray:
    """(seeds, grid) of each seed's windowed mean as it stood at each grid step (NaN before
    its first episode ended and past its last)."""
    mean = rolling(df, column, window)
    rows = []
    for _, g in df.groupby("seed"):
        ends, vals = g["env_steps"].to_numpy(), mean[g.index].to_numpy()
        i = np.searchsorted(ends, grid, side="right") - 1
        v = np.where(i >= 0, vals[i.clip(0)], np.nan)
        rows.append(np.where(grid <= ends[-1], v, np.nan))
    return np.array(rows)


def paired_ratios(df: pd.DataFrame, ref: pd.DataFrame, columns):
    """Mean of each column over the (seed, episode) pairs ``df`` shares with ``ref``, divided by
    ``ref``'s mean over the same pairs (same random numbers); None if they share none."""
    pairs = df.merge(ref, on=["seed", "episode"], suffixes=("", "_ref"))
    return [pairs[c].mean() / pairs[c + "_ref"].mean() for c in columns] if len(pairs) else None


def count(n: int, noun: str) -> str:
    """"1 seed", "2 seeds", "1,000 episodes"."""
    return f"{n:,} {noun}{'' if n == 1 else 's'}"

