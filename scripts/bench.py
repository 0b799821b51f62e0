#!/usr/bin/env python
"""Benchmarks. Each sub-command prints a table and writes ``bench-<name>.json``.

    python scripts/bench.py gp      # cost of one add + one predict per GP (exact, sparse, naive)
    python scripts/bench.py dgpq    # cost per seed-step of the whole DGPQ loop on the square
    python scripts/bench.py kernel  # manifold vs RBF GP regression on discontinuous functions
    python scripts/bench.py push    # block pushing: agent steps per second, share of physics
    python scripts/bench.py qhat    # one evaluation of Q̂ (Eq. 7) against the pairs it holds
    python scripts/bench.py parity  # DQN vs Stable-Baselines3's DQN, the zoo's settings and budgets, 10 seeds
    python scripts/bench.py neural  # DQN and DDPG seed-batched vs the per-seed code, and SB3's DQN
    python scripts/bench.py threads # ms per seed-step at 1 and 2 torch threads, quiet and loaded
    python scripts/bench.py step-parts  # a learning step: the update and the work around it
    python scripts/bench.py bound   # neural learners: ms per seed-step against their arithmetic bound
    python scripts/bench.py same-curves --before OLD/* --after NEW/*   # two versions' curves equal in distribution?
    python scripts/bench.py quick   # reproduce --scale quick: its wall time, time-left guide and estimate
"""
from __future__ import annotations

import argparse
import json
import math
import platform
import sys
import time
from pathlib import Path

import numpy as np
import torch

from trl_dgpq.gp import ExactGP, RBFKernel, SparseOnlineGP

LS, NOISE, DIM = 0.05, 0.1, 2


def timeit(fn, min_time=0.1, min_reps=3, max_reps=200, repeats=5):
    """Seconds per call: the minimum over ``repeats`` rounds of the mean over a round
    (as the timeit module does), after one warm-up call. The minimum is the estimate
    least disturbed by the host's noise, which on this machine comes in bursts."""
    fn()
    best = float("inf")
    for _ in range(repeats):
        reps, start = 0, time.perf_counter()
        while reps < min_reps or (time.perf_counter() - start < min_time and reps < max_reps):
            fn()
            reps += 1
        best = min(best, (time.perf_counter() - start) / reps)
    return best


def naive_add_predict(X, y, x_new, y_new, xq):
    """What the public reproduction does per step: append, then rebuild and invert
    (K + noise I) from scratch for the query (numpy, O(n^3))."""
    X.append(x_new)
    y.append(y_new)
    A = np.asarray(X)
    d2 = ((A[:, None, :] - A[None, :, :]) ** 2).sum(-1)
    K = np.exp(-d2 / (2 * LS ** 2)) + NOISE * np.eye(len(A))
    Kinv = np.linalg.inv(K)
    k = np.exp(-((A - xq) ** 2).sum(-1) / (2 * LS ** 2))
    mean = k @ Kinv @ np.asarray(y)
    var = 1.0 - k @ Kinv @ k
    X.pop()
    y.pop()  # keep n fixed across repetitions
    return mean, var


def bench_gp(args):
    ns = (200, 1000) if args.quick else (200, 1000, 2000, 5000)
    batches = (1, 64)
    gen = torch.Generator().manual_seed(0)
    rnd = lambda *s: torch.rand(*s, generator=gen, dtype=torch.float64)  # noqa: E731
    results = []

    def record(backend, B, n, sec_per_call):
        us = sec_per_call / B * 1e6
        results.append(dict(backend=backend, batch=B, n=n, us_per_add_predict=round(us, 2)))
        print(f"{backend:>7} {B:>6} {n:>6} {us:>14.1f}", flush=True)

    print(f"torch {torch.__version__}, threads {torch.get_num_threads()}, {platform.processor() or platform.machine()}")
    print(f"{'backend':>7} {'batch':>6} {'n':>6} {'us/add+predict':>14}  (per GP)")
    for B in batches:
        k = RBFKernel(LS, 1.0)
        # Sparse: feed the stream and time at each n (cost should be flat in n).
        sp = SparseOnlineGP(k, NOISE, DIM, batch_shape=(B,), budget=args.budget, novelty_tol=1e-3)
        seen = 0
        for n in ns:
            while seen < n:
                sp.add(rnd(B, DIM), rnd(B))
                seen += 1
            record("sparse", B, n, timeit(lambda: (sp.add(rnd(B, DIM), rnd(B)), sp.predict(rnd(B, 1, DIM)))))
        for n in ns:
            need_gb = B * (n + 64) ** 2 * 8 * 3 / 1e9
            if need_gb > args.max_gb:
                print(f"{'exact':>7} {B:>6} {n:>6}  skipped: needs ~{need_gb:.0f} GB (> --max-gb {args.max_gb})")
                continue
            ex = ExactGP(k, NOISE, DIM, batch_shape=(B,), capacity=n + 64)
            ex.set_data(rnd(B, n, DIM), rnd(B, n))

            def step():
                if int(ex.n.max()) >= n + 63:  # back to n points (stay within capacity)
                    ex.n[:] = n
                    ex.L[:, n:, :] = 0
                    ex.L.diagonal(dim1=-2, dim2=-1)[:, n:] = 1
                    ex.z[:, n:] = 0
                ex.add(rnd(B, DIM), rnd(B))
                ex.predict(rnd(B, 1, DIM))
            record("exact", B, n, timeit(step, min_reps=3, max_reps=30, repeats=3))
            del ex
        if B == 1:
            for n in ns:
                X = [x for x in rnd(n, DIM).numpy()]
                y = list(rnd(n).numpy())
                record("naive", B, n, timeit(lambda: naive_add_predict(X, y, rnd(DIM).numpy(), 0.5, rnd(DIM).numpy()),
                                              min_time=0.5, min_reps=1, max_reps=10, repeats=2 if n > 2000 else 3))
    out = Path(args.out or "bench-gp.json")
    meta = dict(torch=torch.__version__, threads=torch.get_num_threads(), budget=args.budget,
                lengthscale=LS, noise_var=NOISE, dim=DIM)
    out.write_text(json.dumps(dict(meta=meta, results=results), indent=1))
    summarise_gp(results)
    print(f"wrote {out}")


def summarise_gp(results):
    get = {(r["backend"], r["batch"], r["n"]): r["us_per_add_predict"] for r in results}
    ns = sorted({r["n"] for r in results})
    if ("naive", 1, 2000) in get and ("exact", 1, 2000) in get:
        print(f"exact vs naive at n=2000 (single GP): {get[('naive', 1, 2000)] / get[('exact', 1, 2000)]:.0f}x faster")
    for B in (1, 64):
        if ("sparse", B, ns[0]) in get:
            print(f"sparse batch {B}: n={ns[-1]} / n={ns[0]} = "
                  f"{get[('sparse', B, ns[-1])] / get[('sparse', B, ns[0])]:.2f}x, "
                  f"max {max(get[('sparse', B, n)] for n in ns):.1f} us per GP")


def bench_dgpq(args):
    """Whole loop (env + agent + collector, its per-episode bookkeeping included) on the
    square, "shaped" preset.

    Per window of ``--window`` batched steps: the wall time of the collector's whole
    ``run`` (so rows, CSV-bound bookkeeping and resets count) divided by the steps, per
    seed (throughput: µs per seed-step = batched step / S), and the median latency of a
    batched step. This machine's host is noisy over tens of seconds, so each figure is
    the minimum over ``--repeats`` windows: early = the first window of fresh runs, late
    = consecutive windows from step ``--steps`` on of one long run. The JSON keeps every
    window's raw per-step times, the repeat counts and the load average.
    """
    import os

    from trl_dgpq.collectors.experiment import build, resolve_config
    from trl_dgpq.collectors.online import OnlineCollector

    def windows(S, gp, start, fresh):
        cfg = resolve_config(env="square", preset="shaped", seeds=list(range(S)), episodes=10 ** 9, gp=gp,
                             budget=args.budget)
        out, env, agent = [], None, None
        for r in range(args.repeats):
            if fresh or env is None:
                env, agent = build(cfg)
                if start:
                    OnlineCollector(env, agent, 10 ** 9, max_total_steps=start, progress=False).run()
            c = OnlineCollector(env, agent, 10 ** 9, max_total_steps=args.window, progress=False)
            t0 = time.perf_counter()
            c.run()
            out.append(dict(wall_s=time.perf_counter() - t0, step_seconds=list(c.step_seconds)))
        return out, agent

    windows(1, "sparse", 0, True)   # warm-up: one-time costs are not "the first 200 steps"
    results = []
    print(f"torch {torch.__version__}, threads {torch.get_num_threads()}; square/shaped, budget {args.budget}; "
          f"load average {os.getloadavg()}")
    print("us/seed-step: throughput, wall of the whole loop / steps / S; latency: median batched step")
    print(f"{'backend':>7} {'seeds':>6} {'steps':>12} {'us/seed-step':>13} {'latency us':>11} {'Q̂ pairs':>8}")
    for gp in args.backends:
        for S in args.seed_counts:
            spans = [(f"0-{args.window}", 0, True)] + ([(f"{args.steps}+", args.steps, False)] if args.steps else [])
            for label, start, fresh in spans:
                t0 = time.perf_counter()
                raw, agent = windows(S, gp, start, fresh)
                us = min(w["wall_s"] / args.window / S * 1e6 for w in raw)
                latency = min(float(np.median(w["step_seconds"])) * 1e6 for w in raw)
                qsize = float(agent.qhat.size().double().mean())
                results.append(dict(backend=gp, seeds=S, steps=label, us_per_seed_step=round(us, 2),
                                    batched_step_latency_us=round(latency, 1), qhat_pairs_per_seed=qsize,
                                    repeats=args.repeats, window=args.window,
                                    raw=[dict(wall_s=w["wall_s"], step_seconds=[round(x, 7) for x in w["step_seconds"]])
                                         for w in raw]))
                print(f"{gp:>7} {S:>6} {label:>12} {us:>13.1f} {latency:>11.0f} {qsize:>8.0f}"
                      f"   ({time.perf_counter() - t0:.0f} s)", flush=True)
    out = Path(args.out or "bench-dgpq.json")
    out.write_text(json.dumps(dict(meta=dict(torch=torch.__version__, threads=torch.get_num_threads(),
                                             env="square", preset="shaped", budget=args.budget,
                                             load_average_end=os.getloadavg(), quick=args.quick,
                                             statistic="min over repeats; us_per_seed_step is throughput "
                                                       "(window wall time / steps / seeds)"),
                                   results=results), indent=1))
    print(f"wrote {out}")


KERNEL_TASKS = {
    # name: (input dim, n_train, f)
    "step1d": (1, 200, lambda x: torch.where(x[:, 0] > 0, 1.0, -1.0).double()),
    "disc2d": (2, 300, lambda x: torch.where(x.sum(-1) > 0, 1.0, -1.0).double() + 0.5 * torch.sin(3 * x[:, 0])),
}


def bench_kernel(args):
    """Held-out RMSE and NLL of an exact GP with an RBF kernel vs a manifold kernel,
    both fitted by NLL (Adam), on a 1-D step and a 2-D function with a discontinuity."""
    from trl_dgpq.gp import ManifoldKernel, fit

    noise_sd, n_test, results = 0.1, 500, []
    print(f"{'task':>7} {'kernel':>9} {'RMSE':>16} {'NLL':>16} {'fit s':>6}   (mean ± sd over {args.seeds} seeds)")
    for task, (dim, n, f) in KERNEL_TASKS.items():
        rows = {"rbf": [], "manifold": []}
        for seed in range(args.seeds):
            g = torch.Generator().manual_seed(seed)
            x = torch.rand(n + n_test, dim, generator=g, dtype=torch.float64) * 2 - 1
            y = f(x) + noise_sd * torch.randn(n + n_test, generator=g, dtype=torch.float64)
            for name in rows:
                kern = (RBFKernel(0.3, 1.0) if name == "rbf" else
                        ManifoldKernel(1, dim, hidden=(10,), lengthscale=0.3,
                                       uniform=lambda N, c: torch.rand(N, c, generator=g, dtype=torch.float64)))
                gp = ExactGP(kern, 0.1, dim, batch_shape=(1,), capacity=n)
                gp.set_data(x[None, :n], y[None, :n])
                t0 = time.perf_counter()
                fit(gp, steps=args.steps, lr=args.lr)
                secs = time.perf_counter() - t0
                m, v = gp.predict(x[None, n:])
                s2 = v[0] + gp.noise[0]
                err = y[n:] - m[0]
                nll = (0.5 * torch.log(2 * math.pi * s2) + err ** 2 / (2 * s2)).mean().item()
                rows[name].append((err.square().mean().sqrt().item(), nll, secs))
        for name, vals in rows.items():
            a = np.asarray(vals)
            r = dict(task=task, kernel=name, seeds=args.seeds, rmse=a[:, 0].mean(), rmse_sd=a[:, 0].std(),
                     nll=a[:, 1].mean(), nll_sd=a[:, 1].std(), fit_s=a[:, 2].mean())
            results.append({k: (round(v, 4) if isinstance(v, float) else v) for k, v in r.items()})
            print(f"{task:>7} {name:>9} {r['rmse']:>8.4f} ± {r['rmse_sd']:.4f} {r['nll']:>8.4f} ± {r['nll_sd']:.4f} "
                  f"{r['fit_s']:>6.1f}", flush=True)
        better = [results[-1][k] < results[-2][k] for k in ("rmse", "nll")]
        print(f"        manifold better than RBF on {task}: RMSE {'yes' if better[0] else 'NO'}, "
              f"NLL {'yes' if better[1] else 'NO'}")
    out = Path(args.out or "bench-kernel.json")
    out.write_text(json.dumps(dict(meta=dict(steps=args.steps, lr=args.lr, noise_sd=noise_sd, n_test=n_test,
                                             hidden=[10]), results=results), indent=1))
    print(f"wrote {out}")


def bench_push(args):
    """Block pushing at S = 1 and 8 seeds: agent steps per second (S / wall time of a batched
    step) with random actions (the env alone) and with DGPQ ("shaped" preset, fresh runs, so
    the first ``--steps`` steps of learning), and the share of DGPQ's step spent in physics
    (pybullet's changeConstraint + stepSimulation: the time inside ``_World.move``).
    Repeated ``--repeats`` times; the figure is the repeat with the least wall time."""
    import os

    from trl_dgpq.envs.push import env as push_module
    from trl_dgpq.collectors.experiment import build, resolve_config
    from trl_dgpq.collectors.online import OnlineCollector

    physics = [0.0]
    move = push_module._World.move

    def timed_move(self, *a):
        t0 = time.perf_counter()
        move(self, *a)
        physics[0] += time.perf_counter() - t0
    push_module._World.move = timed_move

    def one(S, agent):
        cfg = resolve_config(env="push", agent=agent, seeds=list(range(S)), episodes=10 ** 9)
        env, ag = build(cfg)
        OnlineCollector(env, ag, 10 ** 9, max_total_steps=5, progress=False).run()  # warm-up
        physics[0] = 0.0
        c = OnlineCollector(env, ag, 10 ** 9, max_total_steps=args.steps, progress=False)
        c.run()
        env.close()
        wall = float(np.sum(c.step_seconds))
        return dict(step_seconds=[round(x, 7) for x in c.step_seconds], wall_s=wall, physics_s=physics[0])

    results = []
    print(f"torch threads {torch.get_num_threads()}; load average {os.getloadavg()}; {args.steps} batched steps "
          f"x {args.repeats} repeats")
    print(f"{'agent':>7} {'seeds':>6} {'agent steps/s':>14} {'ms/batched step':>16} {'physics share':>14}")
    for agent in ("random", "dgpq"):
        for S in args.seed_counts:
            runs = [one(S, agent) for _ in range(args.repeats)]
            best = min(runs, key=lambda r: r["wall_s"])
            r = dict(agent=agent, seeds=S, agent_steps_per_s=S * args.steps / best["wall_s"],
                     ms_per_batched_step=best["wall_s"] / args.steps * 1e3,
                     physics_share=best["physics_s"] / best["wall_s"], repeats=runs)
            results.append(r)
            print(f"{agent:>7} {S:>6} {r['agent_steps_per_s']:>14.0f} {r['ms_per_batched_step']:>16.2f} "
                  f"{r['physics_share']:>14.1%}", flush=True)
    out = Path(args.out or "bench-push.json")
    out.write_text(json.dumps(dict(meta=dict(torch=torch.__version__, threads=torch.get_num_threads(),
                                             steps=args.steps, load_average_end=os.getloadavg(),
                                             statistic="repeat with the least wall time"),
                                   results=results), indent=1))
    print(f"wrote {out}")


def bench_qhat(args):
    """One evaluation of Q̂ for S seeds and A actions, against the pairs held per row
    (``width``), in a full storage and in one just doubled (``capacity`` = 2 width - 2).
    Storage is filled through ``load_state_dict`` (a format every version reads), so the
    same script times any commit."""
    from trl_dgpq.qhat import LipschitzQ

    S, A, dim = args.seeds, 4, 2
    gen = torch.Generator().manual_seed(0)
    results = []
    print(f"Q̂ evaluation, S = {S}, A = {A}, dim = {dim}, L1; torch threads {torch.get_num_threads()}")
    print(f"{'pairs/row':>9} {'capacity':>9} {'us/call':>9} {'ns/pair':>8}")
    for width in args.widths:
        for cap in (width, 2 * width - 2):               # full, and just doubled
            q = LipschitzQ(S, A, dim, 1.0, 2.0, capacity=cap)
            mu = torch.full((S, A, cap), torch.inf, dtype=torch.float64)
            mu[..., :width] = torch.rand(S, A, width, generator=gen, dtype=torch.float64)
            q.load_state_dict(dict(s=torch.rand(S, A, cap, dim, generator=gen, dtype=torch.float64), mu=mu,
                                   width=width, version=1))
            x = torch.rand(S, dim, generator=gen, dtype=torch.float64)
            sec = timeit(lambda: q(x), repeats=args.repeats)
            r = dict(width=width, capacity=cap, us_per_call=round(sec * 1e6, 2),
                     ns_per_pair=round(sec * 1e9 / (width * S * A), 3))
            results.append(r)
            print(f"{width:>9} {cap:>9} {r['us_per_call']:>9.1f} {r['ns_per_pair']:>8.2f}", flush=True)
    out = Path(args.out or "bench-qhat.json")
    out.write_text(json.dumps(dict(meta=dict(seeds=S, actions=A, dim=dim, threads=torch.get_num_threads(),
                                             repeats=args.repeats, statistic="min over repeats of the mean"),
                                   results=results), indent=1))
    print(f"wrote {out}")


def bench_qhat_index(args):
    """Eq. 7 through the index (``ChunkIndex``) against the full scan, the same Q̂ and queries: ms
    per query (S x A rows), their ratio, and the share of slots the index scanned. The Q̂ is a run's
    (``--checkpoint``: a DGPQ run's checkpoint.pt, queried at states it holds, moved by 1e-3) or a
    synthetic one per width: a random walk in the unit box (dim 5, steps of 0.03) with mu = sum of
    0.8 sin(3 s) plus noise of 0.1, a slope under L = 5 as a Lipschitz envelope's pairs have."""
    from trl_dgpq import qhat as Q

    cases = []
    if args.checkpoint:
        state = torch.load(args.checkpoint, weights_only=False)["agent"]["qhat"]
        used = torch.isfinite(state["mu"][0, 0])
        cases.append((f"checkpoint {args.checkpoint}", state,
                      state["s"][:, 0][:, used][:, ::max(1, int(used.sum()) // args.queries)][:, :args.queries]
                      .transpose(0, 1).contiguous() + 1e-3))
    gen = torch.Generator().manual_seed(0)
    S, A, dim = args.seeds, 3, 5
    for width in ([] if args.checkpoint else args.widths):
        pts = ((torch.randn(S * A, width, dim, generator=gen, dtype=torch.float64) * 0.03).cumsum(1) + 1) % 2 - 1
        mu = (torch.sin(3 * pts) * 0.8).sum(-1) + 0.1 * torch.randn(S * A, width, generator=gen, dtype=torch.float64)
        state = dict(s=pts.view(S, A, width, dim), mu=mu.view(S, A, width), width=width, version=1)
        walk = pts.view(S, A, width, dim)[:, 0, ::max(1, width // args.queries)][:, :args.queries] + 1e-3
        cases.append((f"synthetic, {width:,} pairs a row", state, walk.transpose(0, 1).contiguous()))
    results = []
    print(f"Q̂ through the index against the scan (L = {args.lipschitz}, l1); torch threads {torch.get_num_threads()}")
    for label, state, queries in cases:
        S, A, cap, dim = state["s"].shape
        timed, values = {}, {}
        for name, index_min in (("scan", 10 ** 12), ("index", 1)):
            q = Q.LipschitzQ(S, A, dim, args.lipschitz, 1e9, capacity=cap, index_min=index_min)
            q.load_state_dict(state)
            q(queries[0])                                      # the index is built here, not timed
            timed[name] = timeit(lambda: [q(x) for x in queries], min_reps=1, repeats=args.repeats) / len(queries)
            values[name] = [q(x) for x in queries]
        same = all(torch.equal(a, b) for a, b in zip(values["scan"], values["index"]))
        scanned = _index_scanned(q, queries)
        r = dict(case=label, rows=S * A, width=int(state["width"]), scan_ms=round(timed["scan"] * 1e3, 3),
                 index_ms=round(timed["index"] * 1e3, 3), ratio=round(timed["scan"] / timed["index"], 2),
                 scanned_share=round(scanned, 4), same_values=same)
        results.append(r)
        print(f"  {label}: width {r['width']:,}, scan {r['scan_ms']:.3f} ms, index {r['index_ms']:.3f} ms "
              f"(x{r['ratio']:.2f}); the index scanned {100 * scanned:.1f} % of the slots; values the same: {same}",
              flush=True)
    out = Path(args.out or "bench-qhat-index.json")
    out.write_text(json.dumps(dict(meta=dict(threads=torch.get_num_threads(), repeats=args.repeats,
                                             statistic="min over repeats of the mean per query"),
                                   results=results), indent=1))
    print(f"wrote {out}")


def _index_scanned(q, queries) -> float:
    """The share of Q̂'s slots (rows x width) the index opened, averaged over ``queries``."""
    from trl_dgpq import qhat as Q
    opened = []
    take = Q._take

    def counting(t, rows, at):
        if t is q.index.chunk_mu:
            opened.append(at.numel() * t.shape[-1])
        return take(t, rows, at)
    Q._take = counting
    try:
        for x in queries:
            q(x)
    finally:
        Q._take = take
    return sum(opened) / len(queries) / (q.S * q.A * q.width)


IMPORTS = ("trl_dgpq", "trl_dgpq.dgpq", "trl_dgpq.collectors.experiment")
COUNT_WORLDS = """
import runpy, sys, tempfile, pybullet
connects = [0]
connect = pybullet.connect
def counted(*a, **k):
    connects[0] += 1
    return connect(*a, **k)
pybullet.connect = counted
main = runpy.run_path(sys.argv[1] + "/scripts/train.py", run_name="bench")["main"]
out = tempfile.mkdtemp()
main(["--env", "push", "--agent", "dgpq", "--seeds", "1", "--episodes", "1", "--max-steps", "1", "--no-progress",
      "--out", out + "/run"])
print("WORLDS", connects[0])
"""


def bench_imports(args):
    """Import time of the core (median and least of ``--repeats`` fresh interpreters, from
    ``python -X importtime``: the module's cumulative microseconds), whether it imports a
    simulator, and how many pybullet worlds ``train.py --env push`` builds for a one-seed
    run. ``--checkout DIR`` times another checkout (on PYTHONPATH, before this one)."""
    import os
    import subprocess
    import sys

    root = Path(args.checkout or Path(__file__).resolve().parent.parent).resolve()
    env = dict(os.environ, PYTHONPATH=str(root) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    py = [sys.executable]
    # This venv's editable install maps trl_dgpq.envs and .collectors onto this checkout's folders;
    # another checkout's are imported only where its trl_dgpq/ holds them (links to ../envs, ../collectors).
    where = subprocess.run(py + ["-c", "import trl_dgpq.envs as e, trl_dgpq.collectors as c; "
                                       "print(e.__file__); print(c.__file__)"],
                           env=env, cwd=root, capture_output=True, text=True)
    if where.returncode or not all(Path(f).resolve().is_relative_to(root) for f in where.stdout.split()):
        sys.exit(f"bench.py imports: {root}'s envs/ and collectors/ are not the ones imported there; link them: "
                 f"ln -s ../envs {root}/trl_dgpq/envs; ln -s ../collectors {root}/trl_dgpq/collectors")
    results = dict(checkout=str(root), load_average_start=os.getloadavg(), modules={})
    for module in IMPORTS:
        times = []
        for _ in range(args.repeats):
            err = subprocess.run(py + ["-X", "importtime", "-c", f"import {module}"], env=env, cwd=root,
                                 capture_output=True, text=True, check=True).stderr
            times.append(int(next(line for line in reversed(err.splitlines())
                                  if line.rstrip().endswith("| " + module)).split("|")[1]))
        heavy = subprocess.run(py + ["-c", f"import sys, {module}; print('pybullet' in sys.modules, "
                                           "'gymnasium' in sys.modules)"],
                               env=env, cwd=root, capture_output=True, text=True, check=True).stdout.split()
        results["modules"][module] = dict(us=times, median_ms=float(np.median(times)) / 1e3,
                                          least_ms=min(times) / 1e3, pybullet=heavy[0] == "True",
                                          gymnasium=heavy[1] == "True")
        print(f"import {module:<32} median {np.median(times) / 1e3:7.0f} ms, least {min(times) / 1e3:7.0f} ms; "
              f"pybullet {heavy[0]}, gymnasium {heavy[1]}", flush=True)
    out = subprocess.run(py + ["-c", COUNT_WORLDS, str(root)], env=env, cwd=root, capture_output=True, text=True,
                         check=True)
    worlds = int(next(line.split()[1] for line in out.stdout.splitlines() if line.startswith("WORLDS")))
    results.update(push_worlds_for_one_seed=worlds, load_average_end=os.getloadavg())
    print(f"train.py --env push, 1 seed: {worlds} pybullet worlds built (1 is the run's own)")
    path = Path(args.out or "bench-imports.json")
    path.write_text(json.dumps(results, indent=1))
    print(f"wrote {path}")


def bench_against_published(args):
    """A run of a published experiment again (``--run``: its folder, the same settings and seeds,
    any number of episodes: compared over those both have): its rows against the publication's in every column but the
    timing ones (the run's floats written as the publication writes them), and the CPU time of both
    per window of episodes and in all, with their ratio. What a speed change must show: the same
    rows, in less time."""
    import tempfile

    from trl_dgpq.analysis import published
    from trl_dgpq.analysis.runs import load_run, read_csv_exact
    from trl_dgpq.commands.reproduce import same_sections

    run = load_run(Path(args.run))
    # the baseline: the publication's rows, or another run's (the same settings by the code before a change)
    pub = load_run(Path(args.baseline)) if args.baseline else published.load(args.publication, args.experiment)
    against = args.baseline or args.publication
    mine, theirs = same_sections(run.config), same_sections(pub.config)
    for c in (mine, theirs):        # neither changes a row: a shorter or longer run of the same plan
        for k in ("episodes", "checkpoint_every", "max_memory"):
            c["run"].pop(k, None)
    differ = [f"{s}.{k}" for s in theirs for k in sorted(set(mine[s]) | set(theirs[s])) if mine[s].get(k) != theirs[s].get(k)]
    if differ:
        raise SystemExit(f"{args.run} is not {args.experiment}'s settings: {', '.join(differ)} differ")
    if "cpu_s" not in pub.df:
        raise SystemExit(f"{against} keeps no cpu_s for {args.experiment} (published before it was kept)")
    n = int(min(d.groupby("seed")["episode"].max().min() for d in (run.df, pub.df)))   # every seed has both
    ours, pubs = (d[d.episode <= n].sort_values(["seed", "episode"]).reset_index(drop=True) for d in (run.df, pub.df))
    cols = [c for c in pubs.columns if c not in ("wall_s", "cpu_s", "us_per_step", "job", "env_steps")]
    def as_published(df):   # written and read back as the publication's rows are
        with tempfile.TemporaryDirectory() as tmp:
            df[cols].to_csv(Path(tmp) / "rows.csv", index=False, float_format=published.FLOAT_FORMAT)
            return read_csv_exact(Path(tmp) / "rows.csv")
    written, theirs_rows = as_published(ours), as_published(pubs) if args.baseline else pubs
    differ = [c for c in cols if not written[c].equals(theirs_rows[c])]
    # per episode, the batch's CPU (each row holds its seed's share)
    cpu_pub, cpu_run = (d.groupby("episode")["cpu_s"].sum() for d in (pubs, ours))
    windows = []
    for lo in range(1, n + 1, args.window):
        hi = min(n, lo + args.window - 1)
        p, o = cpu_pub.loc[lo:hi].sum(), cpu_run.loc[lo:hi].sum()
        windows.append(dict(episodes=f"{lo}-{hi}", published_cpu_s=round(float(p), 1), run_cpu_s=round(float(o), 1),
                            ratio=round(float(p / o), 2)))
    p, o = float(pubs.cpu_s.sum()), float(ours.cpu_s.sum())
    total = dict(published_cpu_min=round(p / 60, 1), run_cpu_min=round(o / 60, 1), ratio=round(p / o, 2))
    print(f"{args.experiment}: {args.run} against {against}, episodes 1-{n} of {len(pubs.seed.unique())} seeds "
          f"({len(pubs):,} rows)")
    print(f"  the same rows in {', '.join(cols)}: {not differ}" + (f" (differ: {', '.join(differ)})" if differ else ""))
    print(f"  {'episodes':>11} {'baseline CPU s' if args.baseline else 'published CPU s':>16} {'run CPU s':>10} "
          f"{'ratio':>6}")
    for w in windows:
        print(f"  {w['episodes']:>11} {w['published_cpu_s']:>16,.1f} {w['run_cpu_s']:>10,.1f} {w['ratio']:>6.2f}")
    print(f"  all: {total['published_cpu_min']:,.1f} against {total['run_cpu_min']:,.1f} min of CPU "
          f"({total['ratio']:.2f}x); the run's commit {', '.join(published.commits_of(run))}, the "
          f"{'baseline' if args.baseline else 'publication'}'s {', '.join(published.commits_of(pub))}")
    out = Path(args.out or "bench-against-published.json")
    out.write_text(json.dumps(dict(meta=dict(experiment=args.experiment, run=str(args.run), publication=str(against),
                                             baseline_is_a_run=bool(args.baseline),
                                             episodes=n, columns=cols, run_commits=published.commits_of(run),
                                             statistic="CPU time summed over the rows (each a seed's share of its batch)"),
                                   same_rows=not differ, differ=differ, windows=windows, total=total), indent=1))
    print(f"wrote {out}")


def bench_finished_seeds(args):
    """How much of each published experiment's batch went on after some of its seeds had finished:
    a batch steps all its seeds in lock-step until its last one finishes (its batched steps: the
    most env steps of any seed), so of S x those seed-steps, the ones its seeds did not take were
    taken by finished seeds, which learn nothing. Per experiment, largest CPU first."""
    from trl_dgpq.analysis import published
    from trl_dgpq.commands.reproduce import spent_seconds
    rows = []
    for name in published.manifest(args.publication)["experiments"]:
        df = published.load(args.publication, name, columns=("cpu_s", "wall_s")).df
        per_seed = df.groupby("seed")["steps"].sum()
        batched = int(per_seed.max())
        rows.append(dict(experiment=name, agent=published.recorded_config(args.publication, name)["run"]["agent"],
                         seeds=len(per_seed), batched_steps=batched, seed_steps=int(per_seed.sum()),
                         finished_share=round(1 - float(per_seed.sum()) / (len(per_seed) * batched), 3),
                         cpu_min=round(float(spent_seconds(df).sum()) / 60, 1)))
    rows.sort(key=lambda r: -r["cpu_min"])
    print(f"{'experiment':>36} {'agent':>6} {'S':>3} {'batched steps':>14} {'finished share':>15} {'CPU min':>8}  "
          f"(finished share: of S x batched steps, those its finished seeds took)")
    for r in rows[:args.top]:
        print(f"{r['experiment']:>36} {r['agent']:>6} {r['seeds']:>3} {r['batched_steps']:>14,} "
              f"{r['finished_share']:>15.2f} {r['cpu_min']:>8.1f}")
    out = Path(args.out or "bench-finished-seeds.json")
    out.write_text(json.dumps(dict(meta=dict(publication=str(args.publication)), results=rows), indent=1))
    print(f"wrote {out}")


def _neural():
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    import bench_neural
    return bench_neural


def _quick():
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    import bench_quick
    return bench_quick


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = p.add_subparsers(dest="what", required=True)
    g = sub.add_parser("gp", help="GP add+predict cost per GP vs points seen")
    g.add_argument("--quick", action="store_true", help="n = 200, 1000 only")
    g.add_argument("--budget", type=int, default=100)
    g.add_argument("--max-gb", type=float, default=8.0, help="skip exact cases needing more memory")
    g.add_argument("--out", default=None)
    g.set_defaults(fn=bench_gp)
    d = sub.add_parser("dgpq", help="DGPQ loop cost per seed-step, early and late")
    d.add_argument("--steps", type=int, default=20000, help="late window starts here (0: early only)")
    d.add_argument("--window", type=int, default=200)
    d.add_argument("--repeats", type=int, default=3)
    d.add_argument("--backends", nargs="+", default=["sparse", "exact"], choices=["sparse", "exact"])
    d.add_argument("--seed-counts", nargs="+", type=int, default=[1, 64])
    d.add_argument("--budget", type=int, default=100)
    d.add_argument("--quick", action="store_true", help="under 2 minutes: late window at step 2,000, 2 repeats, "
                                                        "sparse GP only")
    d.add_argument("--out", default=None)
    d.set_defaults(fn=bench_dgpq)
    k = sub.add_parser("kernel", help="manifold vs RBF GP regression, held-out RMSE and NLL")
    k.add_argument("--seeds", type=int, default=5)
    k.add_argument("--steps", type=int, default=300, help="Adam steps of the NLL fit")
    k.add_argument("--lr", type=float, default=0.02)
    k.add_argument("--out", default=None)
    k.set_defaults(fn=bench_kernel)
    b = sub.add_parser("push", help="block pushing: agent steps per second, physics share")
    b.add_argument("--steps", type=int, default=300, help="batched steps per measurement")
    b.add_argument("--repeats", type=int, default=3)
    b.add_argument("--seed-counts", nargs="+", type=int, default=[1, 8])
    b.add_argument("--out", default=None)
    b.set_defaults(fn=bench_push)
    q = sub.add_parser("qhat", help="one Q̂ evaluation against the pairs held")
    q.add_argument("--seeds", type=int, default=64)
    q.add_argument("--widths", nargs="+", type=int, default=[100, 200, 1000, 2000, 4000])
    q.add_argument("--repeats", type=int, default=5)
    q.add_argument("--out", default=None)
    q.set_defaults(fn=bench_qhat)
    qi = sub.add_parser("qhat-index", help="Eq. 7 through Q̂'s index against the full scan")
    qi.add_argument("--checkpoint", default=None, help="a DGPQ run's checkpoint.pt (default: synthetic Q̂s)")
    qi.add_argument("--widths", nargs="+", type=int, default=[16384, 65536, 150000])
    qi.add_argument("--seeds", type=int, default=4)
    qi.add_argument("--lipschitz", type=float, default=5.0)
    qi.add_argument("--queries", type=int, default=50)
    qi.add_argument("--repeats", type=int, default=3)
    qi.add_argument("--out", default=None)
    qi.set_defaults(fn=bench_qhat_index)
    for in_process in (g, d, q, qi):   # timed in this process (the others set their own threads)
        in_process.add_argument("--threads", type=int, default=1,
                                help="torch intra-op threads (1: as every run uses by default)")
        in_process.set_defaults(in_process=True)
    m = sub.add_parser("imports", help="import time of the core; simulators imported; push worlds per run")
    m.add_argument("--repeats", type=int, default=7)
    m.add_argument("--checkout", default=None, help="another checkout to time (default: this one)")
    m.add_argument("--out", default=None)
    m.set_defaults(fn=bench_imports)
    n = sub.add_parser("neural", help="DQN (CartPole, zoo settings) and DDPG (liquidation): new vs old vs SB3")
    n.add_argument("--seed-counts", nargs="+", type=int, default=[1, 4, 10])
    n.add_argument("--dqn-steps", type=int, default=20_000, help="env steps per seed")
    n.add_argument("--ddpg-episodes", type=int, default=100)
    n.add_argument("--threads", type=int, default=1, help="torch threads in every run (the same for all)")
    n.add_argument("--old-rev", default="9d9c0f1", help="the one-learner-per-seed code to compare with")
    n.add_argument("--trees", nargs="+", default=["new", "old"], choices=["new", "old"])
    n.add_argument("--parts", nargs="+", default=["dqn", "sb3", "ddpg"], choices=["dqn", "sb3", "ddpg"])
    n.add_argument("--sb3-python", default=None, help="a Python with stable-baselines3 (see bench_neural.py)")
    n.add_argument("--out", default=None)
    n.set_defaults(fn=lambda a: _neural().bench_neural(a))
    t = sub.add_parser("threads", help="ms per seed-step at 1 and 2 threads, quiet and loaded")
    t.add_argument("--agents", nargs="+", default=["dgpq", "dqn", "ddpg"], choices=["dgpq", "dqn", "ddpg"])
    t.add_argument("--seed-counts", nargs="+", type=int, default=None,
                   help="default: DGPQ 1 and 64, DQN 1 and 10, DDPG 1 and 4")
    t.add_argument("--burners", type=int, default=2, help="busy processes beside the loaded measurements")
    t.add_argument("--out", default=None)
    t.set_defaults(fn=lambda a: _neural().bench_threads(a))
    bd = sub.add_parser("bound", help="neural learners: ms per seed-step against their arithmetic bound")
    bd.add_argument("--learners", nargs="+", default=list(_neural().BOUND_CASES), choices=list(_neural().BOUND_CASES))
    bd.add_argument("--seed-counts", nargs="+", type=int, default=[1, 4, 10])
    bd.add_argument("--threads", type=int, default=1)
    bd.add_argument("--out", default=None)
    bd.set_defaults(fn=lambda a: _neural().bench_bound(a))
    qk = sub.add_parser("quick", help="reproduce --scale quick: wall time, the time-left guide, the estimate")
    qk.add_argument("--workers", type=int, default=2)
    qk.add_argument("--out-dir", default=None, help="the reproduction's folder (default: a new one under runs/); "
                    "with --replay, the earlier run's, where its record's command does not name it")
    qk.add_argument("--out", default=None)
    qk.add_argument("--replay", default=None, metavar="FILE",
                    help="run nothing: replay the guide of an earlier run (this benchmark's JSON) with the estimate "
                         "the checkout makes now")
    qk.add_argument("--publication", default=None, metavar="DIR",
                    help="with --replay: estimate from this publication (default: the committed results/report)")
    qk.set_defaults(fn=lambda a: _quick().bench_quick(a))
    sc = sub.add_parser("same-curves", help="two versions' runs of the same settings and seeds: curves equal "
                                             "in distribution? (IQMs, P(after better), each with its 95 %% CI)")
    sc.add_argument("--before", nargs="+", required=True, metavar="RUN")
    sc.add_argument("--after", nargs="+", required=True, metavar="RUN", help="paired with --before by folder name")
    sc.add_argument("--out", default=None)
    sc.set_defaults(fn=lambda a: _neural().bench_same_curves(a))
    ap = sub.add_parser("against-published", help="a published experiment run again: the same rows? in how much CPU?")
    ap.add_argument("--run", required=True, metavar="DIR", help="the run's folder (train.py --out)")
    ap.add_argument("--experiment", required=True, help="the published experiment it runs again")
    ap.add_argument("--publication", default="results/report", metavar="DIR")
    ap.add_argument("--baseline", default=None, metavar="DIR", help="another run's folder in place of the "
                    "publication (the same settings run by the code before a change): its rows and CPU time")
    ap.add_argument("--window", type=int, default=100, help="episodes per row of the table")
    ap.add_argument("--out", default=None)
    ap.set_defaults(fn=bench_against_published)
    fs = sub.add_parser("finished-seeds", help="a publication's experiments: the share of their batches' steps "
                        "taken by seeds that had finished")
    fs.add_argument("--publication", default="results/report", metavar="DIR")
    fs.add_argument("--top", type=int, default=25, help="rows printed (largest CPU first; the JSON keeps all)")
    fs.add_argument("--out", default=None)
    fs.set_defaults(fn=bench_finished_seeds)
    sp = sub.add_parser("step-parts", help="a learning step of DDPG and DQN: the update and the work around it")
    sp.add_argument("--threads", type=int, default=1)
    sp.add_argument("--warmup", type=int, default=1_100)
    sp.add_argument("--out", default=None)
    sp.set_defaults(fn=lambda a: _neural().bench_step_parts(a))
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    import bench_parity
    bench_parity.add_parser(sub)
    args = p.parse_args(argv)
    if args.what == "threads" and args.seed_counts is None:
        args.seed_counts = dict(dgpq=[1, 64], dqn=[1, 10], ddpg=[1, 4])
    if args.what == "dgpq" and args.quick:
        args.steps, args.repeats, args.backends = min(args.steps, 2000), min(args.repeats, 2), ["sparse"]
    if getattr(args, "in_process", False):   # run in this process: as a run would
        torch.set_num_threads(args.threads)
    args.fn(args)


if __name__ == "__main__":
    main()
