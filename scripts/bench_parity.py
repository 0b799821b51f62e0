"""DQN against Stable-Baselines3's DQN on the zoo's settings and budgets (``bench.py parity``).

For each of CartPole-v1, Acrobot-v1 and MountainCar-v0: SB3's DQN, its seeds one after
another as its users run them, in an environment of its own (``--sb3-python``; SB3 is no
dependency of this package), and ours, the seeds batched in one run of ``train.py``'s
code on the gym env's ``zoo`` preset (raw observations, the zoo's settings in
``envs/gym/presets.py``: one table serves both sides). Per seed: the mean of the last 10
training episodes' returns, and a greedy evaluation of 10 episodes (the zoo reports that).
The summary: median, IQM and its 95 % bootstrap interval (rliable) per side, and whether
our IQM lies inside SB3's interval.

Each side and task is kept in the JSON as it finishes (``--out``), so the parts can run
at different times (``--parts sb3`` now, ``--parts ours`` after a change) and a rerun
skips what is there (``--redo`` reruns)::

    python -m venv /tmp/sb3 && echo "$PWD/.venv/lib/python3.11/site-packages" \\
        > /tmp/sb3/lib/python3.11/site-packages/suite.pth && /tmp/sb3/bin/pip install --no-deps stable-baselines3
    python scripts/bench.py parity --sb3-python /tmp/sb3/bin/python
"""
from __future__ import annotations

import json
import os
import sys
import time
from pathlib import Path

from bench_neural import child

# SB3's DQN on the zoo's settings for one gym id; its seeds one after another. Settings arrive
# in SB3's own names (envs/gym/presets.py ZOO_DQN).
SB3 = r"""
import json, sys, time, torch
import gymnasium as gym
from stable_baselines3 import DQN
from stable_baselines3.common.evaluation import evaluate_policy
spec = json.loads(sys.argv[1])
torch.set_num_threads(spec["threads"])
z = dict(spec["zoo"])
steps = int(z.pop("n_timesteps"))
net_arch = z.pop("net_arch")
out = []
for seed in spec["seeds"]:
    model = DQN("MlpPolicy", gym.make(spec["env_id"]), policy_kwargs=dict(net_arch=list(net_arch)), seed=seed,
                verbose=0, device="cpu", **z)
    t0 = time.perf_counter()
    model.learn(steps)
    wall = time.perf_counter() - t0
    returns = [float(r) for r in model.get_env().envs[0].get_episode_rewards()]
    eval_env = gym.make(spec["env_id"])
    eval_env.reset(seed=10_000 + seed)
    greedy, _ = evaluate_policy(model, eval_env, n_eval_episodes=10, deterministic=True, return_episode_rewards=True)
    out.append(dict(seed=seed, wall_s=wall, returns=returns, last10=sum(returns[-10:]) / len(returns[-10:]),
                    greedy=[float(g) for g in greedy]))
    print(json.dumps(out[-1] | dict(returns=len(returns))), file=sys.stderr, flush=True)
print(json.dumps(out))
"""

# Ours: the seeds batched in one run on the env's "zoo" preset, then a greedy evaluation of
# each seed (learning and exploration off) on the env's evaluation streams.
OURS = r"""
import json, sys, tempfile, time, torch
spec = json.loads(sys.argv[1])
torch.set_num_threads(spec["threads"])
from trl_dgpq.collectors.evaluate import evaluate
from trl_dgpq.collectors.experiment import resolve_config
from trl_dgpq.collectors.runner import RunFolder, start
cfg = resolve_config(env="gym:" + spec["env_id"], agent="dqn", preset="zoo", seeds=spec["seeds"], episodes=10 ** 6,
                     env_steps=spec["env_steps"])
out_dir = tempfile.mkdtemp(prefix="parity-")
t0 = time.perf_counter()
df = start(cfg, RunFolder(out_dir), progress=False)
wall = time.perf_counter() - t0
ev = evaluate(out_dir, episodes=10)
res = []
for seed, rows in df.groupby("seed"):
    returns = rows["return"].astype(float).tolist()
    res.append(dict(seed=int(seed), returns=returns, last10=sum(returns[-10:]) / len(returns[-10:]),
                    greedy=ev[ev.seed == seed]["return"].astype(float).tolist()))
print(json.dumps(dict(wall_s=wall, seeds=res, run=out_dir)))
"""

TASKS = ("CartPole-v1", "Acrobot-v1", "MountainCar-v0")


def iqm_ci(values) -> tuple:
    """(IQM, lower, upper): rliable's interquartile mean and its 95 % bootstrap interval."""
    import numpy as np

    from trl_dgpq.analysis.stats import iqm
    return iqm(np.asarray(values, dtype=float))


def run_side(side: str, env_id: str, args) -> dict:
    spec = dict(threads=args.threads, env_id=env_id, seeds=list(range(args.seeds)))
    t0 = time.perf_counter()
    if side == "sb3":
        from trl_dgpq.envs.gym.presets import ZOO_DQN
        seeds = child(SB3, dict(spec, zoo=ZOO_DQN[env_id]), python=args.sb3_python)
        res = dict(wall_s=sum(s["wall_s"] for s in seeds), seeds=seeds)
    else:
        from trl_dgpq.envs.gym.presets import ZOO_DQN
        res = child(OURS, dict(spec, env_steps=int(ZOO_DQN[env_id]["n_timesteps"])))
    res.update(total_s=time.perf_counter() - t0, load_average_end=os.getloadavg())
    return res


def bench_parity(args) -> None:
    out = Path(args.out or "bench-parity.json")
    results = json.loads(out.read_text()) if out.exists() else {}
    results.setdefault("meta", {}).update(threads=args.threads, seeds=args.seeds)
    for env_id in args.tasks:
        for side in args.parts:
            if side == "sb3" and not args.sb3_python:
                raise SystemExit("bench parity: --sb3-python is needed for the sb3 part")
            key = f"{side}:{env_id}"
            if key in results and not args.redo:
                continue
            print(f"{key}: {args.seeds} seeds, load average {os.getloadavg()[0]:.1f} ...", flush=True)
            results[key] = dict(run_side(side, env_id, args), load_average_start=os.getloadavg())
            out.write_text(json.dumps(results, indent=1))
    summarise(results)
    out.write_text(json.dumps(results, indent=1))
    print(f"wrote {out}")


def summarise(results: dict) -> None:
    """The parity table: per task and side, median and IQM [95 % CI] of the last-10 training
    return and the median greedy evaluation, wall time for all seeds; our IQM inside SB3's CI?"""
    import numpy as np
    print(f"{'task':<15} {'side':<5} {'last-10 median':>15} {'IQM [95% CI]':>26} {'greedy median':>14} {'wall s':>8}")
    table = results.setdefault("summary", {})
    for env_id in TASKS:
        row = {}
        for side in ("sb3", "ours"):
            r = results.get(f"{side}:{env_id}")
            if not r:
                continue
            last10 = [s["last10"] for s in r["seeds"]]
            greedy = [float(np.mean(s["greedy"])) for s in r["seeds"]]
            iqm, lo, hi = iqm_ci(last10)
            row[side] = dict(median=float(np.median(last10)), iqm=iqm, ci=[lo, hi],
                             greedy_median=float(np.median(greedy)), wall_s=r["wall_s"])
            print(f"{env_id:<15} {side:<5} {row[side]['median']:>15.1f} {f'{iqm:.1f} [{lo:.1f}, {hi:.1f}]':>26} "
                  f"{row[side]['greedy_median']:>14.1f} {r['wall_s']:>8.0f}")
        if {"sb3", "ours"} <= row.keys():
            lo, hi = row["sb3"]["ci"]
            row["ours_iqm_in_sb3_ci"] = bool(lo <= row["ours"]["iqm"] <= hi)
            row["sb3_over_ours_wall"] = row["sb3"]["wall_s"] / row["ours"]["wall_s"]
            print(f"{'':<15} ours' IQM inside SB3's CI: {row['ours_iqm_in_sb3_ci']}; "
                  f"wall SB3 / ours {row['sb3_over_ours_wall']:.2f}x")
        table[env_id] = row


def add_parser(sub) -> None:
    p = sub.add_parser("parity", help="DQN vs Stable-Baselines3's DQN: the zoo's settings and budgets, 10 seeds")
    p.add_argument("--sb3-python", default=None, help="a Python with stable-baselines3 (see bench_parity.py)")
    p.add_argument("--parts", nargs="+", choices=("sb3", "ours"), default=["sb3", "ours"])
    p.add_argument("--tasks", nargs="+", choices=TASKS, default=list(TASKS))
    p.add_argument("--seeds", type=int, default=10)
    p.add_argument("--threads", type=int, default=1)
    p.add_argument("--redo", action="store_true", help="rerun parts already in the JSON")
    p.add_argument("--out", default=None, help="the JSON (default bench-parity.json); kept between parts")
    p.set_defaults(fn=bench_parity)


if __name__ == "__main__":  # pragma: no cover
    sys.exit("run it as: python scripts/bench.py parity ...")
