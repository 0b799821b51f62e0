#!/usr/bin/env python
"""Interrupt real runs at random points and check that nothing finished is lost.

    python scripts/crash_check.py                               # 6 trials: SIGINT, SIGTERM, SIGKILL x 2
    python scripts/crash_check.py --trials 2 --signals INT KILL --seeds 3 --episodes 20

First one uninterrupted reference run. Then, per trial, ``scripts/train.py`` with
the same settings is started, sent the signal at a uniformly random moment of its
episode loop, and checked:
  - exit code 130 / 143 with one line on stderr naming --resume and no traceback
    (SIGINT / SIGTERM), status "interrupted"; -9 for SIGKILL (status stays "running");
  - the rows on disk are rows of the reference (timing aside), and per seed its
    episodes 1..k: every finished episode up to the kill is there, none is wrong;
  - ``--resume`` finishes the run, and its episodes.csv equals the reference's.
Prints a table and writes the measurements to --json.
"""
from __future__ import annotations

import argparse
import json
import random
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pandas as pd

from trl_dgpq.collectors.experiment import TIMING_COLUMNS
from trl_dgpq.collectors.runner import read_csv_exact

TRAIN = str(Path(__file__).resolve().parent / "train.py")


def train(*args, **kw):
    return subprocess.Popen([sys.executable, TRAIN, "--no-progress", *args], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, **kw)


def rows(folder: Path) -> pd.DataFrame:
    path = folder / "episodes.csv"
    if not path.exists():
        return pd.DataFrame()
    return read_csv_exact(path).drop(columns=list(TIMING_COLUMNS))


def wait_running(folder: Path, proc, timeout=120.0) -> None:
    """Until the run's status says running (imports and setup are done)."""
    end = time.time() + timeout
    while time.time() < end and proc.poll() is None:
        try:
            if json.loads((folder / "status.json").read_text())["status"] == "running":
                return
        except (OSError, ValueError, KeyError):
            pass
        time.sleep(0.02)
    raise RuntimeError(f"{folder}: the run did not start")


def trial(k: int, sig: str, settings, reference: pd.DataFrame, loop_s: float, work: Path, rng) -> dict:
    out = work / f"trial-{k}-{sig}"
    proc = train(*settings, "--out", str(out))
    wait_running(out, proc)
    delay = rng.uniform(0.0, 0.9 * loop_s)
    time.sleep(delay)
    proc.send_signal(getattr(signal, "SIG" + sig))
    _, err = proc.communicate(timeout=300)
    got = rows(out)
    status = json.loads((out / "status.json").read_text())
    res = dict(trial=k, signal=sig, delay_s=round(delay, 3), exit_code=proc.returncode,
               status=status["status"], rows_on_disk=len(got), stderr=err.strip().splitlines()[-3:])
    checks = {}
    if sig == "KILL":
        checks["exit"] = proc.returncode == -signal.SIGKILL
    else:
        checks["exit"] = proc.returncode == 128 + getattr(signal, "SIG" + sig)
        lines = err.strip().splitlines()
        checks["one line, no traceback"] = len(lines) == 1 and "--resume" in lines[0] and "Traceback" not in err
        checks["status"] = status["status"] == "interrupted" and status["episodes_done"] == len(got)
    if len(got):
        merged = got.merge(reference, how="left", indicator=True)
        checks["rows are the reference's"] = bool((merged["_merge"] == "both").all())
        per_seed = got.groupby("seed").episode.agg(["min", "max", "count"])
        checks["per seed episodes 1..k"] = bool(((per_seed["min"] == 1) & (per_seed["max"] == per_seed["count"])).all())
    resumed = train("--resume", str(out))
    _, rerr = resumed.communicate(timeout=600)
    final = rows(out)
    checks["resume exit 0"] = resumed.returncode == 0
    checks["resumed csv == reference"] = final.equals(reference)
    res["checks"] = checks
    res["ok"] = all(checks.values())
    if resumed.returncode:
        res["resume_stderr"] = rerr.strip().splitlines()[-3:]
    return res


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--trials", type=int, default=6)
    p.add_argument("--signals", nargs="+", default=["INT", "TERM", "KILL"], choices=["INT", "TERM", "KILL"])
    p.add_argument("--seeds", default="4")
    p.add_argument("--episodes", default="60")
    p.add_argument("--checkpoint-every", default="5")
    p.add_argument("--set", nargs="*", default=[], help="more settings for train.py, as KEY=VALUE")
    p.add_argument("--seed", type=int, default=0, help="of the random signal times")
    p.add_argument("--work", default=None, help="folder for the runs (default: a temporary one, removed at the end "
                                                "unless a trial failed)")
    p.add_argument("--json", default="crash-check.json")
    args = p.parse_args(argv)
    rng = random.Random(args.seed)
    settings = ["--seeds", args.seeds, "--episodes", args.episodes, "--checkpoint-every", args.checkpoint_every]
    for item in args.set:
        settings += ["--set", item]
    work = Path(args.work or tempfile.mkdtemp(prefix="crash-check-"))
    try:
        ok = check(args, settings, work, rng)
    except BaseException:
        print(f"runs kept in {work}", file=sys.stderr)
        raise
    if args.work is None and ok:
        shutil.rmtree(work, ignore_errors=True)
    elif not ok:
        print(f"runs kept in {work}", file=sys.stderr)
    return 0 if ok else 1


def check(args, settings, work: Path, rng) -> bool:
    """The reference run and the trials; True if every trial passed every check."""
    ref = train(*settings, "--out", str(work / "reference"))
    _, err = ref.communicate(timeout=600)
    if ref.returncode:
        print(err, file=sys.stderr)
        return False
    reference = rows(work / "reference")
    loop_s = float(read_csv_exact(work / "reference" / "episodes.csv").wall_s.sum())
    print(f"reference: {len(reference)} rows, episode loop {loop_s:.1f} s; runs in {work}")
    results = []
    for k in range(args.trials):
        sig = args.signals[k % len(args.signals)]
        r = trial(k, sig, settings, reference, loop_s, work, rng)
        results.append(r)
        failed = [name for name, ok in r["checks"].items() if not ok]
        print(f"trial {k}: SIG{sig:<4} after {r['delay_s']:5.2f} s: exit {r['exit_code']:>4}, status "
              f"{r['status']:<11}, {r['rows_on_disk']:>4} rows on disk -> "
              f"{'ok' if r['ok'] else 'FAILED: ' + ', '.join(failed)}", flush=True)
    ok = all(r["ok"] for r in results)
    Path(args.json).write_text(json.dumps(dict(settings=settings, reference_rows=len(reference), loop_s=loop_s,
                                               results=results, ok=ok), indent=1))
    print(f"{sum(r['ok'] for r in results)}/{len(results)} trials passed every check; wrote {args.json}")
    return ok


if __name__ == "__main__":
    sys.exit(main())
