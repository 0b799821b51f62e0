"""Compare learners by the environment steps they needed (``scripts/report.py``).

Runs are grouped by env and the env settings that make the task (not those only the agent's
side depends on, ``AGENT_SIDE_SETTINGS``: liquidation's sale grid, gym's observation map).
For each group, ``compare-<env>.png`` (the settings that differ in its name) plots
the domain's measure against environment steps (each seed's mean over its last
``window`` episodes, as it stood at that step; median and IQR over seeds), and
``compare.md`` holds one table:

- steps to threshold (the domain's ``Threshold``): the environment steps a seed had
  taken when the mean of its last few episodes first met it, within the budget;
  median over seeds, counting a seed that never met it as "never" (so the median is
  "never" unless more than half met it), and how many met it;
- at budget: the mean of each seed's last ``window`` episodes that ended within the
  budget (default: the runs' common ``env_steps``, else the fewest steps any of their
  seeds ran), median and IQR over seeds.

Beside each median, the interquartile mean over seeds with its 95 % stratified bootstrap
confidence interval (``stats.py``, by ``rliable``); for steps to threshold a seed that
never met it counts as the budget (so that IQM is a lower bound). Under the table, the
probability that a DGPQ run improves on a DQN run of the same task, with its CI; and
``profiles.png``, rliable's performance profiles of each agent over every task it ran
(at-budget scores, each task scaled to [0, 1] by the worst and best any run had; an
agent with several runs on a task is represented by the first given). And ``results.csv``,
one row per run (``results.py``: the form ``results/`` keeps in the repository).
"""
from __future__ import annotations

import json
import re
import warnings
from pathlib import Path

import numpy as np
import pandas as pd

from . import results
from .runs import Run, load_run
from .stats import iqm, normalised, oriented, probability_of_improvement, profiles
from .summary import at_budget, curve, kernel_fits_per_seed, ms_per_seed_step, steps_to_threshold

WINDOW = 10  # episodes in each seed's running mean: the curves and the at-budget column (and tune's objective)


def default_budget(entries) -> int:
    """The runs' common ``env_steps`` budget, else the fewest steps any of their seeds ran."""
    budgets = {run.config["run"].get("env_steps", 0) for _, run in entries}
    if len(budgets) == 1 and budgets != {0}:
        return budgets.pop()
    return int(min(run.df.groupby("seed")["env_steps"].max().min() for _, run in entries))


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


def fmt_iqm(values, digits: str = ".4g") -> str:
    point, lo, hi = iqm(values)
    return "–" if np.isnan(point) else f"{point:{digits}} [{lo:{digits}}, {hi:{digits}}]"


def improvement_lines(scored, threshold, lower: bool) -> list:
    """P(DGPQ run improves on DQN run), per pair on this task: on steps to threshold (fewer
    is better) and at budget (the domain's direction)."""
    lines = []
    for x_label, x_run, x_steps, x_at in scored:
        for y_label, y_run, y_steps, y_at in scored:
            if x_run.agent != "dgpq" or y_run.agent != "dqn":
                continue
            cells = []
            if threshold is not None:
                cells.append("steps to threshold {:.2f} [{:.2f}, {:.2f}]".format(
                    *probability_of_improvement(-x_steps, -y_steps)))
            cells.append("at budget {:.2f} [{:.2f}, {:.2f}]".format(
                *probability_of_improvement(oriented(x_at, lower), oriented(y_at, lower))))
            lines.append(f"- P({x_label} improves on {y_label}), 95 % CI: " + "; ".join(cells) + ".")
    return lines


def profile_figure(task_scores: dict, out: Path):
    """profiles.png: rliable's performance profiles over the tasks (None if fewer than two
    tasks, or no agent ran them all)."""
    scores = normalised(task_scores)
    if not scores or next(iter(scores.values())).shape[1] < 2:
        return None
    import matplotlib.pyplot as plt

    from .figures import save
    taus = np.linspace(0.0, 1.0, 51)
    curves, cis = profiles(scores, taus)
    fig, ax = plt.subplots(figsize=(6.4, 4.0))
    for algo, y in curves.items():
        line, = ax.plot(taus, y, label=f"{algo} ({scores[algo].shape[1]} tasks x {scores[algo].shape[0]} seeds)")
        ax.fill_between(taus, cis[algo][0], cis[algo][1], color=line.get_color(), alpha=0.2, lw=0)
    ax.set_xlabel("normalised score at budget tau (each task: 0 = worst run's, 1 = best run's)")
    ax.set_ylabel("fraction of runs with score > tau")
    ax.set_title("performance profiles (rliable; band: 95 % bootstrap CI)", fontsize=9)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    return save(fig, out / "profiles.png")


def kernel_fits_cell(run) -> str:
    if "kernel_fits" in run.df:
        return f"{kernel_fits_per_seed(run.df):.1f}"
    return "0" if run.agent == "dgpq" else "–"  # DGPQ with RBF trains no kernel


def task_settings(run) -> dict:
    """The run's env settings that make its task (not those only its agent's side depends on)."""
    side = run.domain.agent_side_settings(run.env_id)
    return {k: v for k, v in run.config["env"].items() if k not in side}


def group_key(run) -> tuple:
    """Runs on the same env with the same task settings share a table and a figure (DGPQ on
    21 sale levels and the AC optimum, which needs none, are runs of one task)."""
    return run.env, json.dumps(task_settings(run), sort_keys=True)


def default_labels(runs) -> list:
    """Each run's agent and preset; where two runs of a group share those, their folder names too."""
    keys = [(group_key(run), run.agent, run.preset) for run in runs]
    return [f"{run.agent} {run.preset}" + (f" ({run.path.name})" if keys.count(k) > 1 else "")
            for k, run in zip(keys, runs)]


def reportable(run) -> None:
    """SelectionSeedsError (one line) if ``run`` may not be reported on (``selection.py``): its
    seeds, those of its config and those its episodes.csv holds, include one its preset was
    chosen on or one outside 0-99. A run without a config is not checked."""
    from trl_dgpq.selection import check_reportable
    if run.config is None:
        return
    seeds = set(run.config["run"].get("seeds") or ()) | {int(s) for s in run.df["seed"].unique()}
    check_reportable({**run.config, "run": {**run.config["run"], "seeds": sorted(seeds)}}, str(run.path))


def report(runs, labels, out: Path, budget=None, window: int = WINDOW, check=None) -> tuple:
    """Figures and the markdown table; returns (written paths, markdown text). ``labels``:
    one per run, or None for each run's agent and preset. ``check``: called with each loaded
    run before anything is written (it raises to refuse one, e.g. ``reportable``)."""
    import matplotlib.pyplot as plt

    from .figures import save
    loaded = [r if isinstance(r, Run) else load_run(r) for r in runs]   # run folders, or runs loaded already
    for run in loaded if check is not None else ():
        check(run)
    labels = labels or default_labels(loaded)
    groups = {}
    for run, label in zip(loaded, labels):
        groups.setdefault(group_key(run), []).append((label, run))
    out.mkdir(parents=True, exist_ok=True)
    written, lines = [], ["# Environment steps to a threshold, and performance at a budget", ""]
    task_scores = {}  # {agent: {task: higher-is-better scores at budget}}, for the profiles
    for (env, _), entries in groups.items():
        first = entries[0][1]
        name = group_name(env, task_settings(first), [json.loads(k[1]) for k in groups if k[0] == env])
        column, ylabel = first.measure()
        for _, run in entries:
            run.need(column)
        threshold = first.domain.threshold(first.env_id)
        lower = first.domain.lower_is_better(first.env_id)
        b = budget or default_budget(entries)
        lines += [f"## {name}", "",
                  f"Budget: {b:,} environment steps per seed. Threshold: "
                  f"{threshold.text if threshold else 'none defined'}. "
                  f"At budget: {ylabel}, mean of each seed's last {window} episodes within the budget; "
                  "median [IQR] over seeds; IQM [95 % CI] over seeds (rliable).", "",
                  "| run | seeds | steps to threshold (median) | steps to threshold, IQM [95 % CI] | at budget "
                  "| at budget, IQM [95 % CI] | kernel fits / seed | ms / seed-step |",
                  "|---|---|---|---|---|---|---|---|"]
        fig, ax = plt.subplots(figsize=(6.8, 4.2))
        grid = np.linspace(0, b, 200)[1:]
        scored = []
        for label, run in entries:
            df = run.df
            steps = steps_to_threshold(df, threshold, b) if threshold else None
            at = at_budget(df, column, b, window)
            censored = steps.fillna(b).to_numpy() if threshold else None  # never: the budget
            scored.append((label, run, censored, at.to_numpy()))
            # an agent with several runs on a task (two kernels, two budgets): its first run given
            task_scores.setdefault(run.agent, {}).setdefault(name, oriented(at.dropna().to_numpy(), lower))
            lines.append(f"| {label} | {df.seed.nunique()} | {fmt_steps(steps) if threshold else '–'} "
                         f"| {fmt_iqm(censored, ',.0f') if threshold else '–'} | {fmt_band(at)} | {fmt_iqm(at)} "
                         f"| {kernel_fits_cell(run)} | {ms_per_seed_step(df):.2f} |")
            c = curve(df, column, window, grid)
            with warnings.catch_warnings():  # grid points no seed has reached yet stay NaN
                warnings.simplefilter("ignore", RuntimeWarning)
                med, lo, hi = (np.nanquantile(c, q, axis=0) for q in (0.5, 0.25, 0.75))
            line, = ax.plot(grid, med, label=f"{label} ({df.seed.nunique()} seeds)")
            ax.fill_between(grid, lo, hi, color=line.get_color(), alpha=0.2, lw=0)
        if threshold and threshold.column == column:
            ax.axhline(threshold.value, color="k", lw=0.8, ls="--", label="threshold")
        ax.set_xlabel("environment steps per seed")
        ax.set_ylabel(f"{ylabel} (mean of last {window})")
        ax.set_title(f"{name}: median and IQR over seeds", fontsize=10)
        ax.legend(fontsize=8)
        written.append(save(fig, out / f"compare-{re.sub(r'[^A-Za-z0-9._-]+', '-', name).strip('-')}.png"))
        lines += ["", *improvement_lines(scored, threshold, lower), ""]
    profile = profile_figure(task_scores, out)
    if profile is not None:
        written.append(profile)
        lines += ["![profiles](profiles.png)", ""]
    text = "\n".join(lines)
    (out / "compare.md").write_text(text)
    written.append(out / "compare.md")
    written.append(results.write([results.row(label, run) for label, run in zip(labels, loaded)],
                                 out / "results.csv"))
    return written, text
