#!/usr/bin/env python
"""Run a sweep: the experiments of a TOML file, their seeds split into jobs, on a pool
of worker processes here (default) or on a Ray cluster.

    python scripts/sweep.py configs/throughput-square.toml --out runs/sweep --workers 2 --seeds-per-job 8
    python scripts/sweep.py configs/throughput-square.toml --out runs/sweep --backend ray [--ray-address HOST:PORT]
    python scripts/sweep.py --resume runs/sweep          # rerun what has not finished
    python scripts/sweep.py configs/compare.toml --out runs/compare --grow   # the file gained experiments:
                                                         # run those, keep the finished ones

The file's format is in ``collectors/sweep.py`` (``read_sweep_file``); every
experiment is checked before any job starts. Each experiment gets a folder under
--out with its jobs' run folders and, once they have all finished, one merged
episodes.csv with a ``job`` column. --out must be a path every Ray node can reach.
Exit codes: 0 all finished, 1 a job failed or was killed (the others finished;
--resume reruns it), 2 a bad request, 130 / 143 interrupted.
"""
from __future__ import annotations

import argparse
import os
import sys

from trl_dgpq.collectors import sweep
from trl_dgpq.collectors.experiment import quiet_torchrl
from trl_dgpq.commands import command, prog, quote


def make_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog=prog("sweep"), description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("file", nargs="?", help="sweep file (TOML)")
    p.add_argument("--out", help="sweep folder")
    p.add_argument("--resume", metavar="OUT", help="continue the sweep in OUT: only unfinished jobs run")
    p.add_argument("--overwrite", action="store_true", help="replace the sweep in --out")
    p.add_argument("--grow", action="store_true",
                   help="--out's sweep (if any) takes the file's experiments it lacks and continues; one it "
                        "holds with other settings is refused by name")
    p.add_argument("--reuse", nargs="+", default=[], metavar="DIR",
                   help="other sweep folders: an experiment not begun here that finished there with the same "
                        "settings is copied in, not run again (its reused.json says from where)")
    p.add_argument("--backend", choices=sweep.BACKENDS, default="local",
                   help="local: worker processes here; ray: one Ray task per job")
    p.add_argument("--workers", type=int, default=os.cpu_count(),
                   help=f"local: worker processes at once (default: the cores, {os.cpu_count()})")
    p.add_argument("--seeds-per-job", type=int, default=None, help="seeds per job (default: an experiment's all)")
    p.add_argument("--ray-address", default=None, help="Ray cluster (default: $RAY_ADDRESS, else a local instance)")
    p.add_argument("--cpus-per-job", type=float, default=1, help="ray: num_cpus of each task")
    return p


def main(argv=None) -> int:
    quiet_torchrl()
    parser = make_parser()
    args = parser.parse_args(argv)
    if args.workers is not None and args.workers < 1:
        parser.error("--workers must be >= 1")
    if args.resume:
        if args.file or args.out or args.overwrite or args.seeds_per_job:
            parser.error("--resume continues a sweep as it was planned: give no file, --out, --overwrite "
                         "or --seeds-per-job with it")
    elif not args.file or not args.out:
        parser.error("give a sweep file and --out (or --resume OUT)")
    if args.grow and args.overwrite:
        parser.error("--grow keeps the sweep in --out, --overwrite replaces it: give one")
    out = args.resume or args.out
    rerun = f"{command('sweep')} --resume {quote(out)}"

    def body() -> int:
        if args.resume:
            experiments, jobs = sweep.load(out)
        else:
            experiments = sweep.read_sweep_file(args.file)
            if args.grow and os.path.isfile(os.path.join(out, sweep.SWEEP)):
                jobs = sweep.grow(out, experiments, args.seeds_per_job)
            else:
                jobs = sweep.plan(experiments, out, args.seeds_per_job)
                sweep.create(out, experiments, jobs, overwrite=args.overwrite)
        if args.reuse:
            jobs = sweep.reuse(out, jobs, args.reuse, log=lambda line: print(line, flush=True))
        print(f"sweep -> {out}: {sweep.describe_jobs(jobs)}; backend {args.backend}", flush=True)
        report = sweep.execute(out, jobs, args.backend, args.workers, args.ray_address, args.cpus_per_job,
                               log=lambda line: print(line, flush=True))
        return sweep.exit_code(report, rerun)
    return sweep.run_script(prog("sweep"), rerun, body)


if __name__ == "__main__":
    sys.exit(main())
