"""Evaluate trained agents: each run's last checkpoint, exploration and learning off.

    python scripts/evaluate.py RUN [RUN ...] [--episodes 10]

A RUN is a run folder (``train.py --out``) or an experiment folder of a sweep. Each seed
plays ``--episodes`` new episodes (its env's random streams keyed for evaluation, so
none is an episode it trained on) with its learned agent acting greedily: DGPQ by Q̂
(ties by its tie stream), DQN with ε = 0, DDPG without OU noise; scripted and random
agents act as in training. Writes RUN/eval.csv (one row per episode, the columns of
episodes.csv) and prints the evaluation's mean of the domain's measure beside the last
training episodes'. Ctrl-C keeps the episodes finished so far in RUN/eval.partial.csv. The checkpoint is only read: its bytes are unchanged.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

from trl_dgpq.commands import guarded, prog


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog=prog("evaluate"), description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("runs", nargs="+", help="run folders or sweep experiment folders")
    p.add_argument("--episodes", type=int, default=10, help="evaluation episodes per seed [10]")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.add_argument("--out", default=None, metavar="DIR",
                   help="write eval.csv here (several runs: DIR/<run>/eval.csv) instead of into each run's folder, "
                        "e.g. for a run one may not write into")
    args = p.parse_args(argv)
    return guarded("evaluate", lambda: run(args))


def run(args) -> int:
    from trl_dgpq.analysis import load_run
    from trl_dgpq.collectors.evaluate import EVAL, evaluate
    from trl_dgpq.collectors.experiment import quiet_torchrl
    quiet_torchrl()
    if args.episodes < 1:
        raise ValueError(f"--episodes must be positive, got {args.episodes}")
    written = []
    for folder in map(Path, args.runs):
        out = None if args.out is None else Path(args.out) / (folder.name if len(args.runs) > 1 else "")
        try:
            df = evaluate(folder, args.episodes, progress=not args.no_progress, out=out)
        except KeyboardInterrupt as stop:   # eval.csv is written whole or not at all: say which runs have one
            left = [str(f) for f in args.runs[len(written):]]
            kept = getattr(stop, "path", None)
            print(f"{prog('evaluate')}: interrupted while evaluating {folder}: "
                  + (f"wrote eval.csv for {', '.join(written)}; " if written else "")
                  + f"no eval.csv written for {', '.join(left)}"
                  + (f"; the {stop.episodes} episodes it finished are in {kept}" if kept else ""), file=sys.stderr)
            return 130
        written.append(str(folder))
        trained = load_run(folder)
        column, label = trained.domain.measure(trained.env_id)
        fmt = lambda value: trained.domain.format_measure(value, trained.env_id)  # noqa: E731
        # each seed's own last episodes: seeds a budget stopped end at different episodes
        train = trained.df.groupby("seed").tail(args.episodes)[column].mean()
        print(f"{folder}: {label}, mean over {df.seed.nunique()} seeds x {args.episodes} evaluation episodes: "
              f"{fmt(df[column].mean())} (mean over each seed's last {args.episodes} training episodes: {fmt(train)}); "
              f"wrote {(out or folder) / EVAL}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
