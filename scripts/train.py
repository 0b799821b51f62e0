#!/usr/bin/env python
"""Run DGPQ on a domain for many seeds at once and write per-episode results.

    python scripts/train.py                      # square, "shaped" preset, 8 seeds
    python scripts/train.py --env square --preset shaped --seeds 10 --episodes 30 --out runs/square-shaped
    python scripts/train.py --preset report --seeds 3-7 --gp exact

Writes OUT/episodes.csv (one row per seed and episode) and OUT/config.json (the
resolved configuration). Same config and seeds -> identical episodes.csv apart
from the timing columns (wall_s, cpu_s, us_per_step).
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import torch  # noqa: E402

from collectors.experiment import parse_seeds, resolve_config, run_experiment  # noqa: E402
from envs import ENVS  # noqa: E402

# CLI flag -> DGPQConfig field (every hyperparameter of a preset can be overridden).
AGENT_FLAGS = {
    "gamma": float, "lipschitz": float, "v_max": float, "sigma_tol2": float, "eps1": float,
    "eps": float, "delta": float, "r_max": float, "noise_var": float, "lengthscale": float,
    "outputscale": float, "metric": str, "gp": str, "budget": int, "novelty_tol": float,
    "kernel": str, "kernel_hidden": tuple, "kernel_skip": bool, "kernel_train_every": int,
    "kernel_min_points": int, "kernel_train_steps": int, "kernel_lr": float,
}


def widths(text: str):
    try:
        w = tuple(int(v) for v in text.split(",") if v.strip())
    except ValueError:
        w = ()
    if not w or min(w) < 1:
        raise argparse.ArgumentTypeError(f"expected positive widths like 10 or 16,16, got {text!r}")
    return w
ENV_FLAGS = {"max_steps": int}


def make_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--env", default="square", choices=sorted(ENVS))
    p.add_argument("--preset", default=None, help="hyperparameter preset of the env (square: shaped, report, paper)")
    p.add_argument("--seeds", default="8", help="count N (0..N-1), range A-B (inclusive) or list a,b,c")
    p.add_argument("--episodes", type=int, default=50)
    p.add_argument("--out", default=None, help="output folder (default runs/<env>-<preset>-<timestamp>)")
    p.add_argument("--no-progress", action="store_true")
    g = p.add_argument_group("DGPQ hyperparameters (override the preset)")
    g.add_argument("--gp", choices=["exact", "sparse"], default=None)
    g.add_argument("--budget", type=int, default=None, help="sparse GP basis-vector budget")
    g.add_argument("--novelty-tol", type=float, default=None)
    g.add_argument("--gamma", type=float, default=None)
    g.add_argument("--lipschitz", type=float, default=None, help="L_Q")
    g.add_argument("--v-max", type=float, default=None)
    g.add_argument("--sigma-tol2", type=float, default=None, help="variance threshold, set directly")
    g.add_argument("--eps1", type=float, default=None, help="optimism margin, set directly")
    g.add_argument("--eps", type=float, default=None, help="Section 5 accuracy (derives sigma_tol2, eps1)")
    g.add_argument("--delta", type=float, default=None, help="Section 5 confidence")
    g.add_argument("--r-max", type=float, default=None)
    g.add_argument("--noise-var", type=float, default=None, help="omega_n^2")
    g.add_argument("--lengthscale", type=float, default=None, help="RBF bandwidth theta")
    g.add_argument("--outputscale", type=float, default=None, help="RBF amplitude s_f^2")
    g.add_argument("--metric", choices=["l1", "l2", "linf"], default=None)
    k = p.add_argument_group("kernel")
    k.add_argument("--kernel", choices=["rbf", "manifold"], default=None,
                   help="manifold: RBF on MLP features trained by NLL (needs --gp exact)")
    k.add_argument("--kernel-hidden", type=widths, default=None, help="hidden widths, e.g. 10 or 16,16")
    k.add_argument("--kernel-skip", action=argparse.BooleanOptionalAction, default=None,
                   help="features x + MLP(x) (default) or the plain MLP output")
    k.add_argument("--kernel-train-every", type=int, default=None, help="train after this many new GP points")
    k.add_argument("--kernel-min-points", type=int, default=None, help="... if the GP holds at least this many")
    k.add_argument("--kernel-train-steps", type=int, default=None)
    k.add_argument("--kernel-lr", type=float, default=None)
    e = p.add_argument_group("environment")
    e.add_argument("--max-steps", type=int, default=None, help="step cap per episode (truncation)")
    return p


def main(argv=None) -> int:
    parser = make_parser()
    args = parser.parse_args(argv)
    pick = lambda flags: {k: getattr(args, k) for k in flags if getattr(args, k) is not None}  # noqa: E731
    try:
        config = resolve_config(args.env, args.preset, parse_seeds(args.seeds), args.episodes,
                                agent=pick(AGENT_FLAGS), env_kwargs=pick(ENV_FLAGS))
    except ValueError as err:
        parser.error(str(err))  # exits 2 with usage, no traceback
    name = f"{config['env']}-{config['preset']}"
    out = Path(args.out) if args.out else Path("runs") / f"{name}-{time.strftime('%Y%m%d-%H%M%S')}"
    out.mkdir(parents=True, exist_ok=True)
    config["versions"] = dict(torch=torch.__version__, python=sys.version.split()[0])
    (out / "config.json").write_text(json.dumps(config, indent=2) + "\n")
    a = config["agent"]
    print(f"{name}: {len(config['seeds'])} seeds x {config['episodes']} episodes, gp={a['gp']}, "
          f"L_Q={a['lipschitz']}, sigma_tol2={a['sigma_tol2']:.4g}, eps1={a['eps1']:.4g}")
    t0 = time.perf_counter()
    df = run_experiment(config, progress=not args.no_progress)
    df.to_csv(out / "episodes.csv", index=False)
    steps = df.pivot(index="episode", columns="seed", values="steps")
    late = df[df.episode >= 3]
    print(f"done in {time.perf_counter() - t0:.1f} s; steps per episode, median over seeds: "
          f"episode 1: {steps.loc[1].median():g}, episodes 3+: {late.steps.median():g}; "
          f"goal reached in {df.terminated.mean():.0%} of episodes; "
          f"{df.wall_s.sum() / df.steps.sum() * 1e6:.0f} us per seed-step")
    print(f"wrote {out / 'episodes.csv'} and {out / 'config.json'}")
    print(f"plot: python scripts/plot.py {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
