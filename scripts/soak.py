#!/usr/bin/env python
"""Soak: resident memory over a long run stays flat after warm-up (issue 21, item 7).

    python scripts/soak.py                       # both soaks below, full size (hours on 2 cores)
    python scripts/soak.py --scale 0.05          # the same, 5 % of the episodes (minutes)

Each soak is a real ``train.py`` process; its resident memory (VmRSS) and the episodes
written are sampled every ``--every`` seconds. Printed: RSS after warm-up (a quarter of
the episodes), its peak and end, and the slope of a least-squares line through the
samples after warm-up, per 1,000 seed-episodes (per hour too, which a loaded host
stretches); and the agent's storage (Q̂ pairs, GP points per seed) over the same span,
which grows as the agent learns and accounts for part of the RSS. The last sample,
taken while the process exits, is left out. ``soak.json`` keeps every sample.

    square       DGPQ "shaped", 1,024 seeds x 200 episodes (Q̂ grows while it learns; its
                 storage doubling shows as steps in RSS)
    liquidation  DGPQ "shortfall" with the sparse GP, 1 seed x 20,000 episodes
"""
from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pandas as pd

ROOT = Path(__file__).resolve().parent.parent
SOAKS = {
    "square": ["--seeds", "1024", "--yes", "--episodes", "200"],
    "liquidation": ["--env", "liquidation", "--agent", "dgpq", "--gp", "sparse", "--seeds", "1", "--episodes", "20000"],
}


def rss_mib(pid: int) -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    return float("nan")


class Rows:
    """Episodes written so far: the newlines of episodes.csv less its header, read incrementally."""

    def __init__(self, path: Path):
        self.path, self.offset, self.lines = path, 0, 0

    def __call__(self) -> int:
        try:
            with open(self.path, "rb") as f:
                f.seek(self.offset)
                chunk = f.read()
        except FileNotFoundError:
            return 0
        self.offset += len(chunk)
        self.lines += chunk.count(b"\n")
        return max(0, self.lines - 1)


def slope(x, y, per: float) -> float:
    """Least-squares slope of y over x, times ``per``; NaN with fewer than 3 points."""
    return float(np.polyfit(x, y, 1)[0] * per) if len(x) >= 3 and np.ptp(x) > 0 else float("nan")


def storage(csv: Path, fraction: float) -> dict:
    """Mean over seeds of the storage columns (Q̂ pairs, GP points) after ``fraction`` of each seed's episodes."""
    df = pd.read_csv(csv)
    cols = [c for c in ("qhat_size", "gp_size") if c in df]
    at = df[df.episode <= (df.groupby("seed").episode.transform("max") * fraction).clip(lower=1)]
    return {c: float(at.groupby("seed")[c].last().mean()) for c in cols}


def soak(name: str, args, scale: float, every: float, work: Path) -> dict:
    argv = list(SOAKS[name])
    i = argv.index("--episodes") + 1
    argv[i] = str(max(2, int(int(argv[i]) * scale)))
    cmd = [sys.executable, str(ROOT / "scripts" / "train.py"), *argv, "--no-progress", "--out", str(work / name)]
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    rows = Rows(work / name / "episodes.csv")
    t0, samples = time.perf_counter(), []
    while proc.poll() is None:
        try:
            samples.append((time.perf_counter() - t0, rss_mib(proc.pid), rows()))
        except OSError:
            break
        time.sleep(every)
    err = proc.stderr.read()
    if proc.returncode:
        raise SystemExit(f"{name}: train.py exited {proc.returncode}: {err.strip()[-300:]}")
    samples = samples[:-1] if len(samples) > 2 else samples  # the last one is taken while the process exits
    t, m, n = (np.array(c, dtype=float) for c in zip(*samples))
    late = n >= n[-1] / 4  # after warm-up: past a quarter of the episodes (time would stretch on a loaded host)
    return dict(name=name, command=cmd[1:], seconds=float(t[-1]), episodes=int(n[-1]),
                peak_mib=float(m.max()), end_mib=float(m[-1]), warm_mib=float(m[late][0]),
                slope_after_warmup_mib_per_1000_episodes=slope(n[late], m[late], 1000),
                slope_after_warmup_mib_per_hour=slope(t[late], m[late], 3600),
                storage_at_warmup=storage(work / name / "episodes.csv", 0.25),
                storage_at_end=storage(work / name / "episodes.csv", 1.0),
                samples=[[float(a), float(b), int(c)] for a, b, c in samples])


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="soak.py", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("which", nargs="*", default=list(SOAKS), help=f"soaks to run: {', '.join(SOAKS)} (default: both)")
    p.add_argument("--scale", type=float, default=1.0, help="fraction of each soak's episodes")
    p.add_argument("--every", type=float, default=1.0, help="seconds between RSS samples")
    p.add_argument("--json", default="soak.json")
    args = p.parse_args(argv)
    unknown = set(args.which) - set(SOAKS)
    if unknown:
        p.error(f"unknown soak {sorted(unknown)}; choose from {list(SOAKS)}")
    with tempfile.TemporaryDirectory(prefix="soak-") as work:
        results = [soak(name, args, args.scale, args.every, Path(work)) for name in args.which]
    for r in results:
        grew = ", ".join(f"{k} {r['storage_at_warmup'][k]:,.0f} -> {v:,.0f}" for k, v in r["storage_at_end"].items())
        print(f"{r['name']}: {r['episodes']:,} seed-episodes in {r['seconds'] / 60:.1f} min; RSS after warm-up "
              f"{r['warm_mib']:.0f} MiB, peak {r['peak_mib']:.0f}, end {r['end_mib']:.0f}; slope after warm-up "
              f"{r['slope_after_warmup_mib_per_1000_episodes']:+.2f} MiB per 1,000 seed-episodes "
              f"({r['slope_after_warmup_mib_per_hour']:+.1f} MiB/h); storage per seed (mean) from warm-up to end: "
              f"{grew} ({len(r['samples'])} samples)")
    Path(args.json).write_text(json.dumps(dict(scale=args.scale, results=results), indent=1))
    print(f"wrote {args.json}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
