"""Analysis of finished runs: load them, pair them, summarise each seed, and draw.

    runs.py      read_csv_exact, Run and load_run (a run folder or a sweep's experiment folder)
    summary.py   one definition each of the per-seed numbers (ms per seed-step, kernel fits),
                 thresholds and steps to them, performance at a budget, pairing by (seed, episode)
    figures.py   the figures every env gets (matplotlib, imported when drawing)
    report.py    the comparison of learners by environment steps (``scripts/report.py``)

What is particular to a domain (its measure and threshold, its own figures and the
sections of the reproduction report) lives in ``envs/<domain>/analysis.py``.
"""
from .runs import Run, load_run, read_csv_exact
from .summary import (Threshold, at_budget, band, count, curve, kernel_fits_per_seed, last_episodes, median_steps,
                      ms_per_seed_step, paired_ratios, rolling, seed_means, steps_to_threshold)

__all__ = ["Run", "load_run", "read_csv_exact", "Threshold", "at_budget", "band", "count", "curve",
           "kernel_fits_per_seed", "last_episodes", "median_steps", "ms_per_seed_step", "paired_ratios", "rolling",
           "seed_means", "steps_to_threshold"]
