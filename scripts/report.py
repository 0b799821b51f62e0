"""Compare learners by the environment steps they needed (issue 11).

    python scripts/report.py RUN [RUN ...] [--labels A B ...] [--budget N] [--out DIR]

A RUN is a run folder (``train.py --out``) or an experiment folder of a sweep
(``sweep.py``: its merged ``episodes.csv``, the config from its first job). Runs are
grouped by env. For each env, ``compare-<env>.png`` plots the env's measure against
environment steps (each seed's mean over its last ``--window`` episodes, as it stood
at that step; median and IQR over seeds), and ``compare.md`` holds one table:

- steps to threshold: the environment steps a seed had taken when the mean of its
  last few episodes (the window in ``THRESHOLDS``: 10, or 1 for MountainCar's flag)
  first met the env's threshold, within the budget; median over seeds, counting a
  seed that never met it as "never" (so the median is "never" unless more than half
  met it), and how many met it;
- at budget: the mean of each seed's last ``--window`` episodes that ended within the
  budget (``--budget``, default: the runs' common ``env_steps``, else the fewest steps
  any of their seeds ran), median and IQR over seeds.
"""
from __future__ import annotations

import argparse
import json
import re
import sys
import warnings
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402

# env -> (CSV column, "<=" or ">=", threshold, episodes in the window, description)
THRESHOLDS = {
    "square": ("steps", "<=", 25, 10, "mean steps per episode <= 25 over 10 episodes"),
    "push": ("success", ">=", 0.9, 10, "success in >= 90 % of 10 episodes"),
    "gym:CartPole-v1": ("return", ">=", 195, 10, "mean return >= 195 over 10 episodes"),
    "gym:MountainCar-v0": ("terminated", ">=", 1, 1, "an episode reaches the flag"),
    "gym:Acrobot-v1": ("return", ">=", -100, 10, "mean return >= -100 over 10 episodes"),
}
# what the curves show, per env (default: the return)
MEASURES = {"square": ("steps", "steps per episode"), "push": ("steps", "steps per episode"),
            "liquidation": ("implementation_shortfall", "implementation shortfall ($)")}


def measure(env: str):
    return MEASURES.get(env, ("return", "return per episode"))


def load_run(folder) -> tuple:
    """(episodes DataFrame, config dict) of a run folder or a sweep's experiment folder."""
    folder = Path(folder)
    configs = [folder / "config.json"] + sorted((folder / "jobs").glob("*/config.json"))
    config = next((c for c in configs if c.exists()), None)
    if config is None or not (folder / "episodes.csv").exists():
        raise ValueError(f"{folder} is not a finished run (needs episodes.csv and a config.json)")
    df = pd.read_csv(folder / "episodes.csv").sort_values(["seed", "episode"], kind="stable")
    df["env_steps"] = df.groupby("seed")["steps"].cumsum()
    return df.reset_index(drop=True), json.loads(config.read_text())


def rolling(df: pd.DataFrame, column: str, window: int, full: bool = False) -> pd.Series:
    """Each seed's mean of ``column`` over its last ``window`` episodes (``full``: only once
    it has that many)."""
    values = df[column].astype(float)
    return values.groupby(df["seed"]).transform(
        lambda v: v.rolling(window, min_periods=window if full else 1).mean())


def steps_to_threshold(df: pd.DataFrame, env: str, budget=None) -> pd.Series:
    """Per seed: env steps when the mean over the env's window of episodes first met its
    threshold, within ``budget`` if given (NaN: never)."""
    column, op, value, window, _ = THRESHOLDS[env]
    mean = rolling(df, column, window, full=True)
    met = (mean <= value if op == "<=" else mean >= value) & (df["env_steps"] <= (budget or np.inf))
    first = df[met].groupby("seed")["env_steps"].first()
    return first.reindex(sorted(df["seed"].unique()))


def at_budget(df: pd.DataFrame, column: str, budget: int, window: int) -> pd.Series:
    """Per seed: mean of ``column`` over its last ``window`` episodes that ended within ``budget``
    (NaN for a seed none of whose episodes did)."""
    within = df[df["env_steps"] <= budget]
    means = within.groupby("seed")[column].apply(lambda v: v.iloc[-window:].mean())
    return means.reindex(sorted(df["seed"].unique()))


def curve(df: pd.DataFrame, column: str, window: int, grid: np.ndarray) -> np.ndarray:
    """(seeds, grid) of each seed's windowed mean as it stood at each grid step (NaN before
    its first episode ended and past its last)."""
    mean = rolling(df, column, window)
    rows = []
    for seed, g in df.groupby("seed"):
        ends, vals = g["env_steps"].to_numpy(), mean[g.index].to_numpy()
        i = np.searchsorted(ends, grid, side="right") - 1
        v = np.where(i >= 0, vals[i.clip(0)], np.nan)
        rows.append(np.where(grid <= ends[-1], v, np.nan))
    return np.array(rows)


def default_budget(entries) -> int:
    """The runs' common ``env_steps`` budget, else the fewest steps any of their seeds ran."""
    budgets = {cfg["run"].get("env_steps", 0) for _, _, cfg in entries}
    if len(budgets) == 1 and budgets != {0}:
        return budgets.pop()
    return int(min(df.groupby("seed")["env_steps"].max().min() for _, df, _ in entries))


def group_name(env: str, settings: dict, others: list) -> str:
    """The env's name, plus the settings where this group differs from the env's other groups."""
    differ = sorted(k for k in settings if any(o.get(k) != settings[k] for o in others))
    return env + (" (" + ", ".join(f"{k}={settings[k]}" for k in differ) + ")" if differ else "")


def fmt_steps(steps: pd.Series) -> str:
    """Median over seeds (a seed that never met the threshold counts as larger than any)."""
    n, met = len(steps), int(steps.notna().sum())
    med = steps.fillna(np.inf).median()
    return f"{'never' if np.isinf(med) else f'{med:,.0f}'} ({met}/{n} seeds met it)"


def fmt_band(v: pd.Series) -> str:
    missing = int(v.isna().sum())
    v = v.dropna()
    text = f"{v.median():.4g} [{v.quantile(0.25):.4g}, {v.quantile(0.75):.4g}]" if len(v) else "–"
    return text + (f" ({missing} seeds: no episode within the budget)" if missing else "")


def report(runs, labels, out: Path, budget=None, window: int = 10) -> tuple:
    """Figures and the markdown table; returns (written paths, markdown text). ``labels``:
    one per run, or None for each run's agent and preset."""
    loaded = [load_run(r) for r in runs]
    labels = labels or [f"{cfg['run']['agent']} {cfg['run']['preset']}" for _, cfg in loaded]
    groups = {}  # runs on the same env with the same env settings
    for (df, cfg), label in zip(loaded, labels):
        key = (cfg["run"]["env"], json.dumps(cfg["env"], sort_keys=True))
        groups.setdefault(key, []).append((label, df, cfg))
    out.mkdir(parents=True, exist_ok=True)
    written, lines = [], ["# Environment steps to a threshold, and performance at a budget", ""]
    for (env, _), entries in groups.items():
        name = group_name(env, entries[0][2]["env"], [json.loads(k[1]) for k in groups if k[0] == env])
        column, ylabel = measure(env)
        b = budget or default_budget(entries)
        threshold = THRESHOLDS.get(env)
        lines += [f"## {name}", "",
                  f"Budget: {b:,} environment steps per seed. Threshold: "
                  f"{threshold[4] if threshold else 'none defined'}. "
                  f"At budget: {ylabel}, mean of each seed's last {window} episodes within the budget; "
                  "median [IQR] over seeds.", "",
                  "| run | seeds | steps to threshold (median) | at budget | kernel fits / seed | ms / seed-step |",
                  "|---|---|---|---|---|---|"]
        fig, ax = plt.subplots(figsize=(6.8, 4.2))
        grid = np.linspace(0, b, 200)[1:]
        for label, df, cfg in entries:
            to = fmt_steps(steps_to_threshold(df, env, b)) if threshold else "–"
            fits = (f"{df.groupby('seed')['kernel_fits'].last().mean():.1f}" if "kernel_fits" in df
                    else "0" if cfg["run"]["agent"] == "dgpq" else "–")  # DGPQ with RBF trains no kernel
            ms = df["wall_s"].sum() / df["steps"].sum() * 1e3
            lines.append(f"| {label} | {df.seed.nunique()} | {to} | {fmt_band(at_budget(df, column, b, window))} "
                         f"| {fits} | {ms:.2f} |")
            c = curve(df, column, window, grid)
            with warnings.catch_warnings():  # grid points no seed has reached yet stay NaN
                warnings.simplefilter("ignore", RuntimeWarning)
                med, lo, hi = (np.nanquantile(c, q, axis=0) for q in (0.5, 0.25, 0.75))
            line, = ax.plot(grid, med, label=f"{label} ({df.seed.nunique()} seeds)")
            ax.fill_between(grid, lo, hi, color=line.get_color(), alpha=0.2, lw=0)
        if threshold and threshold[0] == column:
            ax.axhline(threshold[2], color="k", lw=0.8, ls="--", label="threshold")
        ax.set_xlabel("environment steps per seed")
        ax.set_ylabel(f"{ylabel} (mean of last {window})")
        ax.set_title(f"{name}: median and IQR over seeds", fontsize=10)
        ax.legend(fontsize=8)
        fig.tight_layout()
        path = out / f"compare-{re.sub(r'[^A-Za-z0-9.=_-]+', '-', name).strip('-')}.png"
        fig.savefig(path, dpi=120)
        plt.close(fig)
        written.append(path)
        lines.append("")
    text = "\n".join(lines)
    (out / "compare.md").write_text(text)
    written.append(out / "compare.md")
    return written, text


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="report.py", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("runs", nargs="+", help="run folders or sweep experiment folders")
    p.add_argument("--labels", nargs="+", default=None, help="one per run (default: agent and preset)")
    p.add_argument("--budget", type=int, default=None, help="environment steps per seed for the 'at budget' column")
    p.add_argument("--window", type=int, default=10, help="episodes in the running mean of the curves and table")
    p.add_argument("--out", default=None, help="folder for the figures and compare.md (default: the first run's)")
    args = p.parse_args(argv)
    try:
        if args.labels and len(args.labels) != len(args.runs):
            raise ValueError(f"{len(args.runs)} runs need {len(args.runs)} labels, got {len(args.labels)}")
        if args.window < 1 or (args.budget is not None and args.budget < 1):
            raise ValueError("--window and --budget must be positive")
        written, text = report(args.runs, args.labels, Path(args.out or args.runs[0]), args.budget, args.window)
    except ValueError as err:
        print(f"report.py: error: {err}", file=sys.stderr)
        return 2
    print(text)
    for path in written:
        print("wrote", path)
    return 0


if __name__ == "__main__":
    sys.exit(main())
