"""Figures of a run (or of several runs, overlaid), from OUT/episodes.csv.

    python scripts/plot.py runs/square-shaped
    python scripts/plot.py                      # the newest folder under runs/
    python scripts/plot.py runs/a runs/b --labels rbf manifold --out cmp/

Writes into the (first) run folder, or --out:
    steps_per_episode.png   steps to goal per episode (seed report Fig. 2)
    time_per_step.png       wall time per step per episode, as the console reports it (seed report Fig. 3)
Each curve is the median across seeds with the inter-quartile band.

Runs that were evaluated (``evaluate``: eval.csv) also get eval_returns.png, the
distribution of the evaluation's measure per run. Runs that all belong to a domain with
figures of its own get those instead of the two above (``figures`` in
``envs/<domain>/analysis.py``):
    square                  the two above, and qhat.png (Q̂ of each action over the square for
                            the first DGPQ run's first seed, its pairs, the goal, a greedy
                            evaluation episode, the greedy value and action)
    liquidation             liquidation_cost.png (mean shortfall and ac_cost per block of
                            episodes against the AC optimum, seed report Fig. 6), liquidation_time.png
                            (Fig. 7), comparison.md (costs as ratios to an ac-optimal run on the
                            same (seed, episode) price paths, over the last --last episodes),
                            holdings.png (each learner's holdings x_k on 10 evaluation episodes
                            per seed, from its checkpoint, beside the AC optimum and TWAP)
    push                    push.png (the block's final distance to the goal and the success rate
                            per episode, Fig. 5), push.md (success, steps, fall-offs over the last
                            --last episodes), push.gif (the first learner's first evaluation episode
                            above the oracle's, rendered headless by pybullet's TinyRenderer)
    f16                     f16_reward.png (episode reward per block of --block episodes, median and
                            IQR across seeds, against GWH14's Fig. 3 and the scripted controllers),
                            f16_trace.png (one episode's altitude and elevator: the first learner
                            with a checkpoint against PD and LQR)
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

from trl_dgpq.analysis import load_run
from trl_dgpq.commands import command, guarded, prog, quote


def default_labels(runs) -> list:
    """Agent and preset (what a reader wants in a legend, not a timestamped folder name);
    the folder's name for a run without its config, and where two runs would share a label."""
    labels = [f"{r.agent} {r.preset or 'default'}" if r.config else r.path.name for r in runs]
    return [lab if labels.count(lab) == 1 else r.path.name for lab, r in zip(labels, runs)]


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog=prog("plot"), description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("runs", nargs="*", help="run folders holding episodes.csv (default: newest under runs/)")
    p.add_argument("--labels", nargs="+", default=None)
    p.add_argument("--out", default=None, help="folder for the PNGs (default: the first run folder)")
    p.add_argument("--linear", action="store_true", help="linear y axis for steps")
    p.add_argument("--block", type=int, default=None,
                   help="episodes per plotted mean (liquidation: 100, f16: 10)")
    p.add_argument("--last", type=int, default=None,
                   help="episodes at the end that a domain's table uses (liquidation: 1000, push: 20)")
    args = p.parse_args(argv)

    def refuse(message: str) -> int:
        """One line, as every command's errors (argparse's p.error printed the whole usage first)."""
        print(f"{prog('plot')}: error: {message}", file=sys.stderr)
        return 2
    if args.block is not None and args.block < 1:
        return refuse(f"--block must be >= 1 (episodes per plotted mean), got {args.block}")
    if not args.runs:
        found = sorted(Path("runs").glob("*/episodes.csv"), key=lambda f: f.stat().st_mtime)
        if not found:
            return refuse("no run folder given and none found under runs/")
        args.runs = [str(found[-1].parent)]
    for r in args.runs:
        if not (Path(r) / "episodes.csv").is_file():
            if (Path(r) / "sweep.json").is_file():   # a sweep's folder: its experiments are the runs
                names = sorted(p.parent.name for p in Path(r).glob("*/episodes.csv"))
                return refuse(f"{r} is a sweep's folder: plot its experiments, e.g. {command('plot')} "
                              + " ".join(quote(Path(r) / n) for n in names[:3])
                              + (" ..." if len(names) > 3 else "") if names else
                              f"{r} is a sweep's folder and none of its experiments has finished yet")
            return refuse(f"{r}/episodes.csv not found (run {command('train')} --out {quote(r)} first)")
    if args.labels and len(args.labels) != len(args.runs):
        return refuse(f"give one label per run ({len(args.runs)} runs, {len(args.labels)} labels)")
    return guarded("plot", lambda: draw([load_run(r, need_config=False) for r in args.runs], args.labels,
                                        Path(args.out or args.runs[0]), args))


def draw(runs, labels, out: Path, args) -> int:
    labels = labels or default_labels(runs)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as err:  # guarded would print "[Errno 2] No such file or directory: '/proc/x'"
        raise ValueError(f"cannot create the folder for the figures, {out}: {err.strerror or err} "
                         "(give --out a folder you can write)") from None
    domains = {run.domain and run.domain.name for run in runs}  # None: a run without its config.json
    own = getattr(runs[0].domain.analysis(), "figures", None) if len(domains) == 1 and None not in domains else None
    if len(domains - {None}) > 1:   # one figure of steps and time for all: their measures do not compare
        print(f"note: runs of {len(domains - {None})} domains ({', '.join(sorted(domains - {None}))}) share only the "
              "generic figures (steps and time per episode); plot each domain's runs apart for its own figures",
              file=sys.stderr)
    if own is not None:
        written = own(runs, labels, out, last=args.last, **({} if args.block is None else dict(block=args.block)))
    else:
        from trl_dgpq.analysis.figures import episode_figures
        written = episode_figures(runs, labels, out, logy_steps=not args.linear)
    first = runs[0]
    column, ylabel = first.domain.measure(first.env_id) if first.config else ("return", "return per episode")
    from trl_dgpq.analysis.figures import evaluation_figure
    evaluated = evaluation_figure(runs, labels, out, column, ylabel)
    for path in [*written, *([evaluated] if evaluated else [])]:
        print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
