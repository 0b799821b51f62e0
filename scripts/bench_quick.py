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

``bench.py quick --replay FILE`` runs nothing: it replays an earlier run's guide (FILE, this
benchmark's JSON; the run's folder named in it) with the estimate the checkout makes now, e.g.
after a new publication. Each job starts when a worker frees, in the order the run gave them (by
the estimates it recorded), and ends when its line says; at each progress line the guide
(``sweep.seconds_left``) is asked again with the new costs, and judged as above.
"""
from __future__ import annotations

import json
import os
import re
import subprocess
import sys
import time
from pathlib import Path
from typing import Optional

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


def ended(stamped: list) -> list:
    """[(seconds since start, job name)] of each progress line: the job whose end it reports."""
    return [(t, line.split("] ", 1)[1].rsplit(": ", 1)[0]) for t, line in stamped if "jobs done" in line]


def replay(stamped: list, jobs: list, recorded: dict, workers: int, cost, prior: float = 0.0) -> list:
    """[(seconds since start, guessed seconds left)] at each progress line of a recorded run (its
    ``stamped`` lines; its ``jobs``, sweep.Job in plan order; ``recorded``: job name -> the estimate
    it ran with), the guide asked with ``cost`` and ``prior`` (sweep.rate's) instead. The first
    ``workers`` jobs start at the run's first line, each next one when a job ends (the pool refills
    after the line is printed)."""
    from trl_dgpq.collectors import sweep
    order = sorted(jobs, key=lambda j: -recorded[j.name])   # as reproduce.in_order did, stable
    t0 = stamped[0][0] if stamped else 0.0
    started = {j.name: t0 for j in order[:workers]}
    queue, took, out = order[workers:], [], []
    by_name = {j.name: j for j in jobs}
    for t, name in ended(stamped):      # ``started``: the jobs running, each since when
        took.append((by_name[name], t - started.pop(name)))
        running = [(by_name[n], t - s) for n, s in started.items()]
        out.append((t, sweep.seconds_left(took, running, queue, workers, cost, prior) if queue or running else None))
        if queue:
            started[queue.pop(0).name] = t
    return out


def replayed(path: Path, out: Optional[Path] = None, publication: Optional[Path] = None) -> list:
    """The lines ``bench.py quick --replay`` prints: the recorded guide's hits and the replayed one's
    (``out``: the run's folder, where it is not where the record's command says; ``publication``:
    the published data to estimate from, where not the committed one, e.g. one about to be)."""
    from trl_dgpq.collectors import sweep
    from trl_dgpq.commands import reproduce
    record = json.loads(Path(path).read_text())
    command = record["meta"]["command"].split()
    out, workers = Path(out or command[command.index("--out") + 1]), int(record["meta"]["workers"])
    planned, jobs = sweep.load(out)
    recorded = {j["job"]: j["estimate_s"] for j in record["jobs"]}
    publication = Path(publication or reproduce.PUBLICATION)
    found = reproduce.estimate(planned, publication)
    cost = reproduce.job_cost(planned, found)
    stamped = [tuple(x) for x in record["lines"]]
    then = sum(v["within"] for v in record["guides"])
    now = judged(replay(stamped, jobs, recorded, workers, cost, reproduce.guide_prior(found)))
    total = sum(cost(j) for j in jobs)
    return [f"{path}: {len(jobs)} jobs on {workers} workers, recorded {record['meta']['date']}",
            f"time-left guide within 25 % (or 6 s) of the truth: as run, at {then} of {len(record['guides'])} "
            f"reports; replayed with the estimate from {publication} now, at "
            f"{sum(v['within'] for v in now)} of {len(now)}",
            f"the estimate: {sum(recorded.values()) / 60:.2f} min of one core as run, {total / 60:.2f} now"]


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
    if args.replay:
        for line in replayed(Path(args.replay), args.out_dir, args.publication):
            print(line)
        return
    out = Path(args.out_dir or f"runs/bench-quick-{time.strftime('%Y%m%d-%H%M%S')}")
    if out.exists():
        raise SystemExit(f"bench.py quick: {out} exists: it times a fresh run")
    load_start = os.getloadavg()
    command = [sys.executable, str(ROOT / "scripts" / "reproduce.py"), "--scale", "quick", "--workers",
               str(args.workers), "--out", str(out.resolve())]   # absolute: --replay finds it from anywhere
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
