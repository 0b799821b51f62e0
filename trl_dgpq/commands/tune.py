#!/usr/bin/env python
"""Tune an agent's settings on an env with Optuna: every trial is a run with the same budget.

    python scripts/tune.py --env square --agent dqn --env-steps 10000 --trials 40 --out runs/tune-square-dqn
    python scripts/tune.py --out runs/tune-square-dqn --trials 60              # add 20 trials to that study
    python scripts/tune.py --out runs/tune-square-dqn --write-preset           # best trial -> preset "tuned"
    python scripts/tune.py --out runs/tune-square-dqn --write-preset late      # ... or preset "late"
    python scripts/tune.py --out runs/tune-square-dqn --validate 3 --write-preset
        # the 3 best trials and the base preset again on seeds 1005-1014; the preset: the best there
    python scripts/train.py --env square --agent dqn --preset tuned --seeds 10 --env-steps 10000

The run settings are train's (--episodes, --env-steps, --seeds, --preset, --set KEY=VALUE,
...); the agent's SEARCH_SPACE (beside its config) says what is searched, but for a
setting given here, which is kept. Seeds default to 1000-1004 and validation seeds to
1005-1014; the reporting seeds (0-99) are refused for either: seeds that chose a preset
are never reported on (report refuses runs on them).
The objective is what report.py shows for the domain (docs/running-at-scale.md, "Tuning"):
steps to the threshold, else the measure at the budget, IQM over the seeds. Optuna's TPE
sampler (seeded) picks the settings; a trial runs in stages and MedianPruner stops it
after one if its learning curve is below the median there.

Writes DIR/study.db (Optuna's storage, sqlite:///DIR/study.db) and DIR/trials/NNNN/ (each
trial's run folder), and prints a line per trial and, at the end, the best trial.
Running it again continues the study until it holds --trials trials (ended ones count);
give the settings again or none. A trial stopped by Ctrl-C, SIGTERM or a crash is run
again from its checkpoint. --workers K runs K processes here on the same study; Ray
tasks or other machines fill it too when given the same --storage URL (a database they
all reach, e.g. postgresql://...) and the same DIR on a shared filesystem.
Exit codes: 0 done, 2 a bad request, 130 / 143 interrupted.
"""
from __future__ import annotations

import argparse
import multiprocessing
import os
import signal
import sys

from trl_dgpq.collectors.experiment import cli_owners, quiet_torchrl
from trl_dgpq.commands import command, prog, quote
from trl_dgpq.commands.train import Parser, add_setting_flags, attach_negative_lists, given_settings
from trl_dgpq.config import leaves

PROCESS_FLAGS = ("out", "storage", "write_preset", "force", "validate", "validation_seeds", "set")


def tune_keys():
    from trl_dgpq.study import TuneConfig
    return [leaf.key for leaf in leaves(TuneConfig)]


def make_parser() -> Parser:
    from trl_dgpq.study import DEFAULT_VALIDATION_SEEDS, TuneConfig
    p = Parser(prog=prog("tune"), description=__doc__,
               formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--out", required=True, metavar="DIR", help="the study's folder: study.db and trials/")
    p.add_argument("--storage", metavar="URL", default=None,
                   help="Optuna storage instead of sqlite:///DIR/study.db: processes on other machines or Ray tasks "
                        "fill the same study when given the same URL (and DIR, on a shared filesystem)")
    p.add_argument("--write-preset", nargs="?", const="", default=None, metavar="NAME",
                   help="write the best trial as a preset of this env and agent (envs/<domain>/tuned.json, with its "
                        "provenance): NAME, or without it 'tuned', '<preset>-tuned' if the study ran on another "
                        "preset than the env's default; train.py --preset NAME")
    p.add_argument("--force", action="store_true",
                   help="with --write-preset: replace a preset another study wrote (refused without it)")
    p.add_argument("--validate", type=int, default=0, metavar="K",
                   help="once the trials are done, run the K best and the first (the base preset's) again on "
                        "--validation-seeds at the full budget; --write-preset then writes the best there (five "
                        "tuning seeds rank close settings by luck) [0: none]")
    p.add_argument("--validation-seeds", default=DEFAULT_VALIDATION_SEEDS, metavar="SEEDS",
                   help="seeds for --validate, none of the study's own nor a reporting seed (0-99) "
                        f"[{DEFAULT_VALIDATION_SEEDS}]")
    p.add_argument("--set", metavar="KEY=VALUE", action="append", default=[],
                   help="any run, env or agent setting, e.g. --set gp.noise_var=0.2 (repeatable)")
    add_setting_flags(p, {**{leaf.key: [("TuneConfig", leaf)] for leaf in leaves(TuneConfig)}, **cli_owners()})
    return p


def main(argv=None) -> int:
    quiet_torchrl()
    try:
        return _main(argv)
    except KeyboardInterrupt:  # Ctrl-C before the trials started (a trial started checkpoints instead)
        print("interrupted before the study started", file=sys.stderr)
        return 130


def _main(argv=None) -> int:
    parser = make_parser()
    args = parser.parse_args(attach_negative_lists(sys.argv[1:] if argv is None else list(argv)))
    keys = tune_keys()
    given = given_settings(args, parser, process=(*PROCESS_FLAGS, *keys))
    tune_given = {k: getattr(args, k) for k in keys if getattr(args, k) is not None}
    from trl_dgpq.collectors.experiment import parse_seeds, run_settings
    from trl_dgpq.selection import check_selection_seeds
    from trl_dgpq.study import DEFAULT_VALIDATION_SEEDS, Study
    if args.validate < 0:
        parser.error(f"--validate must be >= 0, got {args.validate}")
    try:
        # studies and validations never touch the reporting seeds: refused before the study is opened
        seeds = run_settings(given).get("seeds")
        if seeds is not None:
            check_selection_seeds(parse_seeds(seeds), "tuning seeds")
        check_selection_seeds(parse_seeds(args.validation_seeds), "validation seeds", DEFAULT_VALIDATION_SEEDS)
        study = Study.open(args.out, args.storage, given, tune_given)
        validation_seeds = study.validation_seeds(parse_seeds(args.validation_seeds)) if args.validate else None
    except ValueError as err:  # everything asked is checked before any trial
        parser.error(str(err))
    trials, workers = study.tune.trials, study.tune.workers
    print(f"study {study.url}: {study.config['run']['agent']} on {study.config['run']['env']}, "
          f"{study.objective.text} ({study.objective.direction}); {study.done(study.load())}/{trials} trials done",
          flush=True)
    signum = run_workers(study, trials, workers)
    if signum:
        storage = f" --storage {args.storage}" if args.storage else ""
        print(f"interrupted by {signal.Signals(signum).name}: {study.done(study.load())}/{trials} trials done; "
              f"continue with: {command('tune')} --out {quote(args.out)}{storage} --trials {trials}", file=sys.stderr)
        return 128 + signum
    print(study.summary(trials), flush=True)
    if args.validate:
        from trl_dgpq.collectors import runner
        try:
            study.validate(args.validate, validation_seeds, log=lambda line: print(line, flush=True))
        except ValueError as err:
            parser.error(str(err))
        except runner.Interrupted as err:
            print(f"interrupted: continue with: {command('tune')} --out {quote(args.out)} --validate {args.validate} "
                  f"--validation-seeds {args.validation_seeds}", file=sys.stderr)
            return 128 + err.signum
    if args.write_preset is not None:
        from trl_dgpq.presets import tuned_name
        try:
            replaced = study.replaces(args.write_preset or tuned_name(study.config["run"]["env"],
                                                                      study.config["run"]["preset"]))
            name, path = study.write_preset(args.write_preset or None, force=args.force)
        except ValueError as err:
            parser.error(str(err))
        if replaced:
            print(f"replaced {replaced}")
        run = study.config["run"]
        print(f"wrote preset '{name}' to {path}: {command('train')} --env {run['env']} --agent {run['agent']} "
              f"--preset {name}")
    return 0


def run_workers(study, trials: int, workers: int) -> int:
    """Fill the study here (one worker) or with ``workers`` processes; the signal that stopped
    them, or 0."""
    from trl_dgpq.study import Stopped, stop_on_signals, work, worker
    if workers == 1:
        with stop_on_signals() as stop:
            try:
                work(study, trials, stop, log=lambda line: print(line, flush=True))
            except Stopped as err:
                return err.signum
        return 0
    ctx = multiprocessing.get_context("spawn")  # fresh processes: torch and SQLite connections are not forked
    procs = [ctx.Process(target=worker, args=(str(study.out), study.url, study.request, trials))
             for _ in range(workers)]
    caught = []

    def forward(signum, frame):  # a terminal's Ctrl-C reaches them already; a kill of this process does not
        if not caught:
            caught.append(signum)
            for p in procs:
                if p.pid and p.is_alive():
                    os.kill(p.pid, signum)
    previous = {s: signal.signal(s, forward) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        for p in procs:
            p.start()
        for p in procs:
            p.join()
    finally:
        for s, h in previous.items():
            signal.signal(s, h)
    if caught:
        return caught[0]
    stopped = [p.exitcode - 128 for p in procs if p.exitcode in (128 + signal.SIGINT, 128 + signal.SIGTERM)]
    if stopped:
        return stopped[0]
    failed = [p.exitcode for p in procs if p.exitcode]
    if failed:
        raise SystemExit(f"{prog('tune')}: a worker ended with exit code {failed[0]}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
