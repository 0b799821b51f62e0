"""``bench.py quick``: how long ``reproduce --scale quick`` takes, and how well its time-left guide
and its plan's estimate did (issue 53: the quick scale within 5 minutes on a quiet 2-core machine,
the guide within 25 % of the truth at every report).

It runs ``scripts/reproduce.py --scale quick`` into a fresh folder, stamping each line of its
output with the time it arrived. Then, from that output and the folder alone:
- the wall time in all, of the sweep (to its last progress line) and of the report after it;
- each progress line's guess of the time left against the truth (the sweep's end minus the
  line's time), within 25 % or 6 s (the line prints tenths of a minute);
- each job's CPU time in its episodes (the rows' ``cpu_s``) against its estimate
  (``reproduce.job_cost``, what the plan and the guide use), with and without the start it adds
  to each job: a job's start is not in its rows.
The load average at the start and the end says how quiet the machine was. Raw lines, per-job
figures and loads go to the JSON.
"""
from __future__ import annotations

import json
import os
import re
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
GUESS = re.compile(r"~([\d.]+) (min|h) left")


def guesses(stamped: list) -> list:
    """[(seconds since start, guessed seconds left or None)] of each progress line."""
    out = []
    for t, line in stamped:
        if "jobs done" in line:
            m = GUESS.search(line)
            out.append((t, float(m.group(1)) * (3600 if m.group(2) == "h" else 60) if m else None))
    return out


def judged(points: list, tolerance: float = 0.25, resolution: float = 6.0) -> list:
    """Each guess before the last line against the truth (the last line's time minus its own)."""
    end = points[-1][0]
    return [dict(at_s=round(t, 1), guess_s=g, truth_s=round(end - t, 1),
                 within=abs(g - (end - t)) <= max(tolerance * (end - t), resolution))
            for t, g in points[:-1] if g is not None]


def per_job(out: Path) -> list:
    """Each job's estimate and the CPU time in its rows."""
    import pandas as pd
    from trl_dgpq.collectors import runner, sweep
    from trl_dgpq.commands import reproduce
    planned, jobs = sweep.load(out)
    cost = reproduce.job_cost(planned, reproduce.estimate(planned, reproduce.PUBLICATION))
    rows = []
    for job in jobs:
        df = pd.read_csv(Path(job.folder) / runner.EPISODES, usecols=["cpu_s"])
        rows.append(dict(job=job.name, estimate_s=round(cost(job), 3),
                         steps_estimate_s=round(cost(job) - reproduce.JOB_START_S, 3),   # a fresh job: one start
                         cpu_in_episodes_s=round(float(df.cpu_s.sum()), 3)))
    return rows


def summary(total: float, points: list, verdicts: list, jobs: list) -> list:
    """The lines bench.py quick prints: wall times, the guide's hits, CPU time against the estimate."""
    if not points:
        return [f"wall {total / 60:.1f} min; no progress line (no job ran)"]
    sweep_s = points[-1][0]
    estimate, cpu = sum(j["estimate_s"] for j in jobs), sum(j["cpu_in_episodes_s"] for j in jobs)
    steps = sum(j["steps_estimate_s"] for j in jobs)
    ratio = f" (x{cpu / estimate:.2f}" if estimate > 0 else " (no estimate"
    ratio += f"; x{cpu / steps:.2f} its steps alone, {steps / 60:.2f}" if steps > 0 else ""
    return [f"reproduce --scale quick, {len(jobs)} jobs",
            f"wall {total / 60:.1f} min: the sweep {sweep_s / 60:.1f}, the report after it {(total - sweep_s) / 60:.1f}",
            f"time-left guide within 25 % (or 6 s) of the truth at {sum(v['within'] for v in verdicts)} of its "
            f"{len(verdicts)} reports",
            f"CPU time in the episodes {cpu / 60:.2f} min of one core against the estimate's {estimate / 60:.2f}"
            f"{ratio}; the estimate counts each job's start, the rows do not)"]


def bench_quick(args) -> None:
    out = Path(args.out_dir or f"runs/bench-quick-{time.strftime('%Y%m%d-%H%M%S')}")
    if out.exists():
        raise SystemExit(f"bench.py quick: {out} exists: it times a fresh run")
    load_start = os.getloadavg()
    command = [sys.executable, str(ROOT / "scripts" / "reproduce.py"), "--scale", "quick", "--workers",
               str(args.workers), "--out", str(out)]
    t0 = time.perf_counter()
    stamped = []
    with subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, bufsize=1) as proc:
        for line in proc.stdout:
            stamped.append((time.perf_counter() - t0, line.rstrip("\n")))
            print(line, end="", flush=True)
    total = time.perf_counter() - t0
    points = guesses(stamped)
    verdicts = judged(points) if points else []
    jobs = per_job(out) if proc.returncode == 0 else []   # a failed run's folders may lack rows
    path = Path(args.out or "bench-quick.json")
    path.write_text(json.dumps(dict(   # first: a failed run's lines are what tells why
        meta=dict(command=" ".join(command), workers=args.workers, load_average_start=load_start,
                  load_average_end=os.getloadavg(), date=time.strftime("%Y-%m-%d %H:%M"), exit_code=proc.returncode),
        wall_s=round(total, 1), sweep_s=round(points[-1][0], 1) if points else None, guides=verdicts, jobs=jobs,
        lines=[[round(t, 2), line] for t, line in stamped]), indent=1))
    if proc.returncode != 0:
        raise SystemExit(f"bench.py quick: the reproduction ended with exit code {proc.returncode} (its lines in {path})")
    for line in summary(total, points, verdicts, jobs):
        print(line)
    print(f"wrote {path}; the run stays in {out}; load average {load_start} at the start, {os.getloadavg()} "
          "at the end")
