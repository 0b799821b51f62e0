#!/usr/bin/env python
"""Soak: resident memory over a long run stays flat after warm-up (issue 21, item 7).

    python scripts/soak.py                       # both soaks below, full size (hours on 2 cores)
    python scripts/soak.py --scale 0.05          # the same, 5 % of the episodes (minutes)

Each soak is a real ``train.py`` process; its resident memory (VmRSS) is sampled every
``--every`` seconds from /proc. Printed: the peak and final RSS and the slope of a
least-squares line through the samples after warm-up (the first quarter of the run),
in MiB per hour; the last sample, taken while the process exits, is left out. ``soak.json`` keeps every sample.

    square       DGPQ "shaped", 1,024 seeds x 50 episodes (Q̂ and the sparse GPs fill, then
                 reach their steady size)
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

ROOT = Path(__file__).resolve().parent.parent
SOAKS = {
    "square": ["--seeds", "1024", "--yes", "--episodes", "50"],
    "liquidation": ["--env", "liquidation", "--agent", "dgpq", "--gp", "sparse", "--seeds", "1", "--episodes", "20000"],
}


def rss_mib(pid: int) -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    return float("nan")


def soak(name: str, args, scale: float, every: float, work: Path) -> dict:
    argv = list(SOAKS[name])
    i = argv.index("--episodes") + 1
    argv[i] = str(max(2, int(int(argv[i]) * scale)))
    cmd = [sys.executable, str(ROOT / "scripts" / "train.py"), *argv, "--no-progress", "--out", str(work / name)]
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    t0, samples = time.perf_counter(), []
    while proc.poll() is None:
        try:
            samples.append((time.perf_counter() - t0, rss_mib(proc.pid)))
        except OSError:
            break
        time.sleep(every)
    err = proc.stderr.read()
    if proc.returncode:
        raise SystemExit(f"{name}: train.py exited {proc.returncode}: {err.strip()[-300:]}")
    samples = samples[:-1] if len(samples) > 2 else samples  # the last one is taken while the process exits
    t, m = (np.array(c) for c in zip(*samples)) if samples else (np.zeros(1), np.zeros(1))
    late = t >= t[-1] / 4
    slope = float(np.polyfit(t[late], m[late], 1)[0] * 3600) if late.sum() >= 3 else float("nan")
    return dict(name=name, command=cmd[1:], seconds=float(t[-1]), peak_mib=float(m.max()), end_mib=float(m[-1]),
                slope_after_warmup_mib_per_hour=slope, samples=[[float(a), float(b)] for a, b in samples])


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
        print(f"{r['name']}: {r['seconds'] / 60:.1f} min, RSS peak {r['peak_mib']:.0f} MiB, end {r['end_mib']:.0f} MiB, "
              f"slope after warm-up {r['slope_after_warmup_mib_per_hour']:+.1f} MiB/h ({len(r['samples'])} samples)")
    Path(args.json).write_text(json.dumps(dict(scale=args.scale, results=results), indent=1))
    print(f"wrote {args.json}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
