"""Compare learners by the environment steps they needed.

    python scripts/report.py RUN [RUN ...] [--labels A B ...] [--budget N] [--out DIR]

A RUN is a run folder (``train.py --out``) or an experiment folder of a sweep
(``sweep.py``: its merged ``episodes.csv``, the config from its first job). Runs are
grouped by env. For each env, ``compare-<env>.png`` plots the env's measure against
environment steps and ``compare.md`` holds one table: steps to the domain's threshold
and performance at a budget (``trl_dgpq/analysis/report.py`` says how each is counted).

    trl-dgpq report results/report

rebuilds a published reproduction (REPORT.md, claims.md, results.csv, summary.md and the
figures drawn from episodes) from its per-episode data alone (``data/``; no runs/ folder).

A run on seeds its preset was chosen on (a study's tuning or validation seeds, in the
preset's provenance) or on seeds outside 0-99 is refused before anything is written:
seeds that chose anything are never reported on. ``--unpublished`` reports on any seeds
(a look at a study's trials, say); nothing it writes may be published.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

from trl_dgpq.analysis.report import WINDOW, report, reportable
from trl_dgpq.commands import guarded, prog


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog=prog("report"), description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("runs", nargs="+", help="run folders or sweep experiment folders")
    p.add_argument("--labels", nargs="+", default=None, help="one per run (default: agent and preset)")
    p.add_argument("--budget", type=int, default=None, help="environment steps per seed for the 'at budget' column")
    p.add_argument("--window", type=int, default=WINDOW, help="episodes in the running mean of the curves and table")
    p.add_argument("--out", default=None, help="folder for the figures and compare.md (default: the first run's)")
    p.add_argument("--unpublished", action="store_true",
                   help="a look at runs on any seeds: nothing it writes may be published (without it, runs on "
                        "seeds their preset was tuned or validated on, or outside 0-99, are refused)")
    args = p.parse_args(argv)
    return guarded("report", lambda: run(args))


def run(args) -> int:
    from trl_dgpq.analysis import published
    if len(args.runs) == 1 and published.is_published(args.runs[0]):   # a publication: rebuild it from its data
        from trl_dgpq.commands.reproduce import rebuild
        print("wrote", rebuild(Path(args.runs[0])), "and the rest from", Path(args.runs[0]) / published.DATA)
        return 0
    if args.labels and len(args.labels) != len(args.runs):
        raise ValueError(f"{len(args.runs)} runs need {len(args.runs)} labels, got {len(args.labels)}")
    if args.window < 1 or (args.budget is not None and args.budget < 1):
        raise ValueError("--window and --budget must be positive")
    from trl_dgpq.selection import SelectionSeedsError
    try:
        written, text = report(args.runs, args.labels, Path(args.out or args.runs[0]), args.budget, args.window,
                               check=None if args.unpublished else reportable)
    except SelectionSeedsError as err:
        raise SelectionSeedsError(f"{err} (--unpublished: a look at it that is not to be published)") from None
    print(text)
    for path in written:
        print("wrote", path)
    return 0


if __name__ == "__main__":
    sys.exit(main())
