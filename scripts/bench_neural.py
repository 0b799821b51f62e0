"""The neural baselines' benchmarks (``bench.py neural`` and ``bench.py threads``).

Each measurement runs in a child process, so that a checkout of another commit
(``--old-rev``: the one-learner-per-seed code) or another environment
(``--sb3-python``: Stable-Baselines3, installed there and not in this package's
dependencies) can be timed by the same code:

    python -m venv /tmp/sb3 && echo "$PWD/.venv/lib/python3.11/site-packages" \\
        > /tmp/sb3/lib/python3.11/site-packages/suite.pth && /tmp/sb3/bin/pip install --no-deps stable-baselines3
    python scripts/bench.py neural --sb3-python /tmp/sb3/bin/python
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent

# rl-baselines3-zoo's CartPole-v1 DQN (hyperparams/dqn.yml), epsilon over 16% of the budget
ZOO_CARTPOLE = dict(lr=2.3e-3, batch_size=64, buffer_size=100_000, learning_starts=1_000, gamma=0.99,
                    target_update_interval=10, train_freq=256, gradient_steps=128, eps_end=0.04, hidden=(256, 256))

# A run of ours (this checkout or another one on PYTHONPATH): wall time of run_experiment,
# seed-steps, and the last 10 episodes' returns per seed.
OURS = r"""
import json, sys, time, torch
spec = json.loads(sys.argv[1])
torch.set_num_threads(spec["threads"])
from trl_dgpq.collectors.experiment import resolve_config, run_experiment
cfg = resolve_config(**spec["config"])
cfg["run"]["threads"] = spec["threads"]
t0 = time.perf_counter()
df = run_experiment(cfg, progress=False, max_total_steps=spec.get("max_total_steps"))
wall = time.perf_counter() - t0
last10 = df.groupby("seed")["return"].apply(lambda r: float(r.tail(10).mean())).tolist()
print(json.dumps(dict(wall_s=wall, seed_steps=int(df.steps.sum()), episodes=len(df), last10=last10,
                      step_seconds_sum=float(sum(df.attrs["step_seconds"])),
                      batched_steps=len(df.attrs["step_seconds"]))))
"""

# Stable-Baselines3's DQN on the zoo's settings, its seeds one after another as its users run them.
SB3 = r"""
import json, sys, time, torch
import gymnasium as gym
from stable_baselines3 import DQN
spec = json.loads(sys.argv[1])
torch.set_num_threads(spec["threads"])
z = spec["zoo"]
out = []
for seed in range(spec["seeds"]):
    env = gym.make("CartPole-v1")
    model = DQN("MlpPolicy", env, learning_rate=z["lr"], batch_size=z["batch_size"], buffer_size=z["buffer_size"],
                learning_starts=z["learning_starts"], gamma=z["gamma"],
                target_update_interval=z["target_update_interval"],
                train_freq=z["train_freq"], gradient_steps=z["gradient_steps"], exploration_fraction=0.16,
                exploration_final_eps=z["eps_end"], policy_kwargs=dict(net_arch=list(z["hidden"])), seed=seed,
                verbose=0, device="cpu")
    t0 = time.perf_counter()
    model.learn(spec["steps"])
    wall = time.perf_counter() - t0
    rets = [ep["r"] for ep in model.ep_info_buffer][-10:]
    out.append(dict(seed=seed, wall_s=wall, last10=float(sum(rets) / len(rets))))
print(json.dumps(out))
"""


def child(code: str, spec: dict, python: str = sys.executable, tree: Path = REPO) -> dict:
    env = dict(os.environ, PYTHONPATH=str(tree), OMP_NUM_THREADS=str(spec["threads"]))
    res = subprocess.run([python, "-c", code, json.dumps(spec)], env=env, cwd=tempfile.gettempdir(),
                         capture_output=True, text=True)
    if res.returncode:
        raise RuntimeError(f"benchmark child failed:\n{res.stderr[-3000:]}")
    return json.loads(res.stdout.strip().splitlines()[-1])


def old_tree(rev: str) -> Path:
    """A detached worktree of ``rev`` (made once, in the temp dir)."""
    path = Path(tempfile.gettempdir()) / f"trl-dgpq-{rev}"
    if not path.exists():
        subprocess.run(["git", "-C", str(REPO), "worktree", "add", "--detach", str(path), rev], check=True,
                       capture_output=True)
    # envs/ and collectors/ install as trl_dgpq.envs and trl_dgpq.collectors: without these links the
    # editable install's finder would serve this checkout's folders to the old tree's package
    for folder in ("envs", "collectors"):
        link = path / "trl_dgpq" / folder
        if (path / folder).is_dir() and not link.exists():
            link.symlink_to(Path("..") / folder)
    return path


def dqn_spec(S: int, steps: int, threads: int) -> dict:
    agent = dict(ZOO_CARTPOLE, exploration_steps=int(0.16 * steps))
    return dict(threads=threads, config=dict(env="gym:CartPole-v1", agent="dqn", seeds=list(range(S)),
                                             episodes=10 ** 6, env_steps=steps, **agent))


def bench_neural(args) -> None:
    load = os.getloadavg()
    print(f"load average at start {load}; torch threads in every run: {args.threads}")
    results = dict(meta=dict(load_average_start=load, threads=args.threads, old_rev=args.old_rev,
                             dqn_steps=args.dqn_steps, ddpg_episodes=args.ddpg_episodes), dqn=[], ddpg=[], sb3=None)
    trees = {"new": REPO, "old": old_tree(args.old_rev)}
    if "dqn" in args.parts:
        print(f"DQN, CartPole-v1, the zoo's settings, {args.dqn_steps} env steps per seed (whole runs)")
        print(f"{'seeds':>6} {'code':>5} {'wall s':>8} {'ms/seed-step':>13} {'last-10 return (median)':>24}")
        for S in args.seed_counts:
            for code in args.trees:
                r = child(OURS, dqn_spec(S, args.dqn_steps, args.threads), tree=trees[code])
                r.update(seeds=S, code=code, ms_per_seed_step=r["wall_s"] / r["seed_steps"] * 1e3)
                results["dqn"].append(r)
                med = sorted(r["last10"])[len(r["last10"]) // 2]
                print(f"{S:>6} {code:>5} {r['wall_s']:>8.1f} {r['ms_per_seed_step']:>13.3f} {med:>24.1f}", flush=True)
    if "sb3" in args.parts and args.sb3_python:
        S = max(args.seed_counts)
        runs = child(SB3, dict(threads=args.threads, seeds=S, steps=args.dqn_steps, zoo=ZOO_CARTPOLE),
                     python=args.sb3_python)
        total = sum(r["wall_s"] for r in runs)
        results["sb3"] = dict(seeds=S, runs=runs, wall_s=total, ms_per_seed_step=total / (S * args.dqn_steps) * 1e3)
        print(f"SB3 DQN, {S} seeds one after another: {total:.1f} s, "
              f"{results['sb3']['ms_per_seed_step']:.3f} ms per seed-step", flush=True)
    if "ddpg" in args.parts:
        print(f"DDPG, liquidation (shortfall), 4 seeds, {args.ddpg_episodes} episodes")
        for code in args.trees:
            spec = dict(threads=args.threads, config=dict(env="liquidation", agent="ddpg", seeds=[0, 1, 2, 3],
                                                          episodes=args.ddpg_episodes))
            r = child(OURS, spec, tree=trees[code])
            r.update(code=code, ms_per_seed_step=r["wall_s"] / r["seed_steps"] * 1e3)
            results["ddpg"].append(r)
            print(f"{code:>5}: {r['wall_s']:.1f} s, {r['ms_per_seed_step']:.3f} ms per seed-step", flush=True)
    summarise(results)
    results["meta"]["load_average_end"] = os.getloadavg()
    out = Path(args.out or "bench-neural.json")
    out.write_text(json.dumps(results, indent=1))
    print(f"load average at end {results['meta']['load_average_end']}; wrote {out}")


def summarise(results: dict) -> None:
    """The issue's ratios, each from runs of this one invocation."""
    by = {(r["seeds"], r["code"]): r for r in results["dqn"]}
    ratios = {}
    for S in sorted({s for s, _ in by}):
        if (S, "new") in by and (S, "old") in by:
            ratios[f"dqn_old_over_new_S{S}"] = by[S, "old"]["wall_s"] / by[S, "new"]["wall_s"]
    sb3 = results.get("sb3")
    if sb3 and (sb3["seeds"], "new") in by:
        ratios["dqn_sb3_over_new"] = sb3["wall_s"] / by[sb3["seeds"], "new"]["wall_s"]
    ddpg = {r["code"]: r for r in results["ddpg"]}
    if {"old", "new"} <= ddpg.keys():
        ratios["ddpg_old_over_new"] = ddpg["old"]["ms_per_seed_step"] / ddpg["new"]["ms_per_seed_step"]
    results["ratios"] = ratios
    for k, v in ratios.items():
        print(f"{k:>24}: {v:.2f}x")


# One point of the threads measurement: ms per seed-step over a window of batched steps
# after a warm-up (learning under way), at the given threads.
CHILD_START = r"""
import json, sys, time, torch
spec = json.loads(sys.argv[1])
torch.set_num_threads(spec["threads"])
from trl_dgpq.collectors.experiment import build, resolve_config
from trl_dgpq.collectors.online import OnlineCollector
"""
RUN_WINDOW = r"""
env, agent = build(resolve_config(**spec["config"]))
S = env.batch_size[0]
col = OnlineCollector(env, agent, 10 ** 9, progress=False)
col.max_total_steps = spec["warmup"]
col.run()
col.step_seconds.clear()
col.max_total_steps = spec["window"]
col.run()
"""
WINDOW = CHILD_START + RUN_WINDOW + r"""
print(json.dumps(dict(ms_per_seed_step=sum(col.step_seconds) / len(col.step_seconds) / S * 1e3)))
"""

THREAD_CASES = {
    "dgpq": dict(env="square", agent="dgpq", preset="shaped", warmup=300, window=600),
    "dqn": dict(env="gym:CartPole-v1", agent="dqn", warmup=1_100, window=1_024, **ZOO_CARTPOLE),
    "ddpg": dict(env="liquidation", agent="ddpg", warmup=300, window=1_000),
}


def bench_threads(args) -> None:
    """ms per seed-step at 1 and 2 threads, quiet and with ``--burners`` busy processes
    beside (a loaded machine), for each agent and seed count."""
    results = []
    print(f"{'agent':>6} {'seeds':>6} {'load':>7} {'1 thread':>9} {'2 threads':>10}  (ms per seed-step)")
    for load in ("quiet", "loaded"):
        burners = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in
                   range(args.burners if load == "loaded" else 0)]
        try:
            for agent in args.agents:
                case = dict(THREAD_CASES[agent])
                warmup, window = case.pop("warmup"), case.pop("window")
                for S in args.seed_counts[agent] if isinstance(args.seed_counts, dict) else args.seed_counts:
                    row = dict(agent=agent, seeds=S, load=load, load_average=os.getloadavg())
                    for threads in (1, 2):
                        spec = dict(threads=threads, warmup=warmup, window=window,
                                    config=dict(case, seeds=list(range(S)), episodes=10 ** 9))
                        row[f"threads_{threads}"] = child(WINDOW, spec)["ms_per_seed_step"]
                    results.append(row)
                    print(f"{agent:>6} {S:>6} {load:>7} {row['threads_1']:>9.3f} {row['threads_2']:>10.3f}",
                          flush=True)
        finally:
            for b in burners:
                b.kill()
    out = Path(args.out or "bench-threads.json")
    out.write_text(json.dumps(dict(meta=dict(burners=args.burners, cpus=os.cpu_count()), results=results), indent=1))
    print(f"wrote {out}")


def bench_step_parts(args) -> None:
    """Where a learning step's time goes, per batched step (µs): one gradient step, and
    the work around it (replay sample and write, the stored transition, acting, the env),
    after ``--warmup`` steps of learning. In this process, at ``--threads``."""
    import time

    import torch

    from trl_dgpq.collectors.experiment import build, resolve_config
    from trl_dgpq.collectors.online import OnlineCollector
    torch.set_num_threads(args.threads)
    results = []
    for agent, env_name, S in (("ddpg", "liquidation", 4), ("dqn", "gym:CartPole-v1", 10)):
        extra = ZOO_CARTPOLE if agent == "dqn" else {}
        env, ag = build(resolve_config(env=env_name, agent=agent, seeds=list(range(S)), episodes=10 ** 9, **extra))
        col = OnlineCollector(env, ag, 10 ** 9, max_total_steps=args.warmup, progress=False)
        col.run()

        def timed(fn, n=200):
            fn()
            t0 = time.perf_counter()
            for _ in range(n):
                fn()
            return (time.perf_counter() - t0) / n * 1e6
        batch = ag.replay.sample(ag.batch_size)
        td = col.td.clone()
        td["action"] = ag.act(col.td)
        out, _ = env.step_and_maybe_reset(td.clone())
        stored = ag.stored(out)
        row = dict(agent=agent, seeds=S, update_us=timed(lambda: ag.update(batch)),
                   replay_sample_us=timed(lambda: ag.replay.sample(ag.batch_size)),
                   replay_write_us=timed(lambda: ag.replay.add(stored)), stored_us=timed(lambda: ag.stored(out)),
                   act_us=timed(lambda: ag.act(col.td)),
                   env_step_us=timed(lambda: env.step_and_maybe_reset(td.clone())))
        row["around_update_us"] = row["replay_sample_us"] + row["replay_write_us"] + row["stored_us"] + row["act_us"]
        results.append(row)
        print(", ".join(f"{k} {v:.0f}" if isinstance(v, float) else f"{k} {v}" for k, v in row.items()), flush=True)
    out = Path(args.out or "bench-step-parts.json")
    out.write_text(json.dumps(dict(meta=dict(threads=args.threads, load_average=os.getloadavg()), results=results),
                              indent=1))
    print(f"wrote {out}")


# One learner's cost per seed-step against its arithmetic bound: the collector's wall time over a
# window after learning started (the whole step: env, act, replay, updates), then the same window
# again under torch's FlopCounterMode (the matrix products of every forward, backward and target,
# as torch counts them) with the optimisers' steps counted by a hook. The bound is
# FLOPs / the core's matrix-product peak + the optimiser's memory traffic / the core's bandwidth
# (Adam reads parameter, gradient and both moments and writes three of them back: 28 bytes per
# fp32 parameter, the least any Adam can move), both measured in the same child just before.
BOUND = CHILD_START + r"""
from torch.optim.optimizer import register_optimizer_step_post_hook
from torch.utils.flop_counter import FlopCounterMode

def best(fn, n):
    fn()
    times = []
    for _ in range(n):
        t0 = time.perf_counter(); fn(); times.append(time.perf_counter() - t0)
    return min(times)
a, b = torch.randn(1024, 1024), torch.randn(1024, 1024)
peak = 2 * 1024 ** 3 / best(lambda: a @ b, 10)                     # FLOP/s
big, dst = torch.randn(16 * 2 ** 20), torch.empty(16 * 2 ** 20)    # 64 MiB each
bandwidth = 2 * big.numel() * 4 / best(lambda: dst.copy_(big), 10)  # bytes/s, read + write
""" + RUN_WINDOW + r"""
wall = sum(col.step_seconds)
steps = {"n": 0, "params": 0}
def counted(opt, args, kwargs):
    steps["n"] += 1
    steps["params"] += sum(p.numel() for g in opt.param_groups for p in g["params"])
hook = register_optimizer_step_post_hook(counted)
with FlopCounterMode(display=False) as fc:
    col.run()
hook.remove()
seed_steps = S * spec["window"]
flops = fc.get_total_flops() / seed_steps
adam_bytes = 28 * steps["params"] / seed_steps
bound = flops / peak + adam_bytes / bandwidth
print(json.dumps(dict(ms_per_seed_step=wall / seed_steps * 1e3, mflop_per_seed_step=flops / 1e6,
                      adam_kb_per_seed_step=adam_bytes / 1e3, bound_ms_per_seed_step=bound * 1e3,
                      peak_gflops=peak / 1e9, bandwidth_gbs=bandwidth / 1e9,
                      optimizer_steps_per_env_step=steps["n"] / spec["window"])))
"""

# The learners of the goal 1, each at its domain's default settings (DQN on CartPole: the zoo's).
BOUND_CASES = {
    "dqn-cartpole": dict(config=dict(env="gym:CartPole-v1", agent="dqn"), warmup=1_024, window=1_024),
    "ddpg-liquidation": dict(config=dict(env="liquidation", agent="ddpg"), warmup=200, window=600),
    "td3-liquidation": dict(config=dict(env="liquidation", agent="td3"), warmup=1_010, window=300),
    "dqn-f16": dict(config=dict(env="f16", agent="dqn"), warmup=300, window=600),
}


def bench_bound(args) -> None:
    """ms per seed-step against the arithmetic bound, per learner and seed count, one thread."""
    results = []
    print(f"load average at start {os.getloadavg()}; {args.threads} torch thread(s)")
    print(f"{'learner':>17} {'S':>3} {'ms/seed-step':>13} {'bound ms':>9} {'ratio':>6} {'MFLOP':>7} "
          f"{'Adam kB':>8} {'vs S=1':>7}")
    for name in args.learners:
        case = BOUND_CASES[name]
        first = None
        for S in args.seed_counts:
            spec = dict(threads=args.threads, warmup=case["warmup"], window=case["window"],
                        config=dict(case["config"], seeds=list(range(S)), episodes=10 ** 9))
            r = child(BOUND, spec)
            first = first or r["ms_per_seed_step"]
            r.update(learner=name, seeds=S, ratio=r["ms_per_seed_step"] / r["bound_ms_per_seed_step"],
                     cheaper_than_S1=first / r["ms_per_seed_step"], load_average=os.getloadavg())
            results.append(r)
            print(f"{name:>17} {S:>3} {r['ms_per_seed_step']:>13.3f} {r['bound_ms_per_seed_step']:>9.3f} "
                  f"{r['ratio']:>6.1f} {r['mflop_per_seed_step']:>7.2f} {r['adam_kb_per_seed_step']:>8.1f} "
                  f"{r['cheaper_than_S1']:>6.2f}x", flush=True)
    print(f"peak {results[-1]['peak_gflops']:.0f} GFLOP/s, bandwidth {results[-1]['bandwidth_gbs']:.1f} GB/s "
          f"(measured in each child; the last one's)")
    out = Path(args.out or "bench-bound.json")
    out.write_text(json.dumps(dict(meta=dict(threads=args.threads, load_average_end=os.getloadavg()),
                                   results=results), indent=1))
    print(f"load average at end {os.getloadavg()}; wrote {out}")


def whole_and_second_half(df, column: str) -> dict:
    """Per seed: the mean of ``column`` over all its episodes (the curve's area per episode) and
    over the second half of its own episodes (not ``summary.seed_means``' one window for all
    seeds: a run with an env-step budget ends each seed at its own episode)."""
    from trl_dgpq.analysis.summary import seed_means
    half = df.episode > df.groupby("seed").episode.transform("max") / 2
    return {"whole run": seed_means(df, column), "second half": df[half].groupby("seed")[column].mean()}


def bench_same_curves(args) -> None:
    """Runs of the same settings and seeds by two versions of the code (``--before``, ``--after``,
    paired by folder name): per learner and statistic, each version's IQM over seeds [95 % CI]
    and P(after improves on before) [95 % CI] (rliable's). The rule, fixed before the runs:
    the curves are equal in distribution (nothing shows otherwise) when every P's interval holds
    0.5. Also each run's ms per seed-step (both versions run side by side, one core each)."""
    from trl_dgpq.analysis.claims import improvement_interval
    from trl_dgpq.analysis.runs import load_run
    from trl_dgpq.analysis.stats import iqm
    from trl_dgpq.analysis.summary import ms_per_seed_step

    before = {Path(f).name: f for f in args.before}
    after = {Path(f).name: f for f in args.after}
    if set(before) != set(after):
        sys.exit(f"bench same-curves: --before and --after name other runs: {sorted(before)} against {sorted(after)}")
    rows, holds = [], True
    print(f"{'run':>17} {'statistic':>12} {'IQM before [95 % CI]':>30} {'IQM after [95 % CI]':>30} "
          f"{'P(after better) [95 % CI]':>26} {'ms/seed-step before, after':>27}")
    for name in sorted(before):
        b, a = load_run(before[name]), load_run(after[name])
        column, label = b.measure()
        lower = b.domain.lower_is_better(b.env_id)
        if sorted(b.df.seed.unique()) != sorted(a.df.seed.unique()):
            sys.exit(f"bench same-curves: {name}: the two runs are on other seeds")
        ms = (ms_per_seed_step(b.df), ms_per_seed_step(a.df))
        mb, ma = whole_and_second_half(b.df, column), whole_and_second_half(a.df, column)
        for stat in mb:
            xb, xa = mb[stat].sort_index().to_numpy(), ma[stat].sort_index().to_numpy()
            better = improvement_interval(xa, xb, lower)
            p = (better.point, better.low, better.high)
            holds &= p[1] <= 0.5 <= p[2]
            ib, ia = iqm(xb), iqm(xa)
            rows.append(dict(run=name, measure=label, lower_is_better=bool(lower), statistic=stat,
                             iqm_before=ib, iqm_after=ia, p_after_better=p, ms_per_seed_step=ms,
                             seeds_before=xb.tolist(), seeds_after=xa.tolist()))
            print(f"{name:>17} {stat:>12} {'{:.4g} [{:.4g}, {:.4g}]'.format(*ib):>30} "
                  f"{'{:.4g} [{:.4g}, {:.4g}]'.format(*ia):>30} {'{:.2f} [{:.2f}, {:.2f}]'.format(*p):>26} "
                  f"{ms[0]:>13.3f} {ms[1]:>7.3f} ({ms[0] / ms[1]:.2f}x)", flush=True)
    verdict = ("equal in distribution: every interval holds 0.5" if holds
               else "NOT shown equal: an interval excludes 0.5")
    print(f"measure: each run's domain measure ({', '.join(sorted({r['measure'] for r in rows}))}); "
          f"{verdict}")
    out = Path(args.out or "bench-same-curves.json")
    out.write_text(json.dumps(dict(meta=dict(before=args.before, after=args.after, load_average_end=os.getloadavg(),
                                             verdict=verdict, seeds=max(len(r["seeds_after"]) for r in rows)),
                                   results=rows), indent=1))
    print(f"wrote {out}")
