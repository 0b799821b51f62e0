"""What the analysis says about the F-16: the episode's reward, against GWH14's Figure 3.

GWH14's DGPQ goes from about −525 to about −47 by episodes 100–200 (L_Q = 5) and from
about −514 to about −113 by episodes 900–1,000 (L_Q = 10). The references here, on seeds
100–107 and the default settings, are the PD law (−37), the quantised LQR (−41), doing
nothing (−135) and a random elevator (−324). A stable flight: a mean episode reward
over 10 episodes within 10 % of PD's, −41 or better.
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd

from trl_dgpq.analysis import Threshold, ms_per_seed_step, rolling, seed_means

MEASURE = ("return", "episode reward")
TERMINATED = "left the flight envelope"
THRESHOLD = Threshold("return", ">=", -41, 10, "mean episode reward >= -41 (PD's -37 minus 10%) over 10 episodes")

# What of the aircraft's model a run uses (claims.py: its claims are variants, counted apart).
MODEL_KNOWLEDGE = {
    "env.potential=lqr": "potential: the LQR's value on the linearised model",
    "run.agent=lqr": "the LQR of the linearised model",
}
# GWH14's Figure 3 as read from the paper: (episode, reward) marks per Lipschitz constant.
PAPER = {5.0: [(1, -525), (150, -47)], 10.0: [(1, -514), (950, -113)]}


def episodes_to_stable(df: pd.DataFrame) -> pd.Series:
    """Per seed: the first episode at which the mean reward of its last 10 met THRESHOLD
    (NaN: never)."""
    met = THRESHOLD.met(rolling(df, THRESHOLD.column, THRESHOLD.window, full=True))
    first = df[met].groupby("seed")["episode"].first()
    return first.reindex(sorted(df["seed"].unique()))


def window_reward(df: pd.DataFrame, first: int, last: int) -> float:
    """Mean episode reward over episodes first..last of every seed (NaN if none ran)."""
    return float(df.loc[df.episode.between(first, last), "return"].mean())


# ------------------------------------------------------------ one flight, for the trace figure
def fly(env, policy) -> dict:
    """Seed row 0's next episode under ``policy`` (a callable td -> actions), learning off:
    {"t": s, "h": ft, "elevator": -1/0/+1, "reward": the episode's}."""
    from trl_dgpq.collectors.evaluate import episode_steps
    td = env.reset()
    t, h, e, total = [0.0], [float(td["state"][0, 0])], [], 0.0
    for td, nxt, _ in episode_steps(env, policy, td, row=0):
        e.append(int(td["action"][0]) - 1)
        t.append(t[-1] + env.cfg.dt * env.cfg.decision_steps)  # a decision holds the elevator this long
        h.append(float(nxt["state"][0, 0]))
        total += float(nxt["reward"][0])
    return dict(t=np.array(t), h=np.array(h), elevator=np.array(e), reward=total)


def flights(folder: Path) -> dict:
    """{name: flight} for the learner whose checkpoint is in ``folder`` (a run, or a sweep
    experiment's first job) and for PD and LQR, on the same next episode of its first seed
    (the env restored from the checkpoint: the noise of an episode it never trained on)."""
    from trl_dgpq.agents import agent_class
    from trl_dgpq.collectors.evaluate import Frozen, jobs, restore
    config, env, agent, checkpoint = restore(jobs(folder)[0])
    out = {}
    for name in (config["run"]["agent"], "pd", "lqr"):
        env.load_state_dict(checkpoint["env"])
        if name in ("pd", "lqr"):
            cls = agent_class(name, config["run"]["env"])
            agent = cls.make(cls.Config(), env.info, list(config["run"]["seeds"]))
        out[name] = fly(env, Frozen(agent).act)  # the learner with exploration off
    return out


def trace_figure(folder, out: Path, title: str = "", label: str = ""):
    """f16_trace.png: altitude error and elevator over one episode, the learner against PD
    and LQR (``flights``), and what it draws as f16_trace.json.xz. With ``folder`` None (no
    checkpoint: a publication rebuilt from its data), drawn from that file (None if there is none)."""
    import matplotlib.pyplot as plt

    from trl_dgpq.analysis.figures import load_drawn, save, save_drawn
    data = out / "f16_trace.json.xz"
    if folder is not None:
        drawn = {name: {k: (v.tolist() if hasattr(v, "tolist") else v) for k, v in f.items()}
                 for name, f in flights(folder).items()}
        save_drawn(data, dict(label=label, flights=drawn))
    got = load_drawn(data, fresh=folder is not None)
    if got is None:
        return None
    label = got["label"]
    fig, (ax, bx) = plt.subplots(2, 1, figsize=(6.4, 5.2), sharex=True)
    for i, (name, f) in enumerate(got["flights"].items()):
        t, elevator = np.asarray(f["t"]), np.asarray(f["elevator"])
        ax.plot(t, f["h"], lw=1.2, label=f"{name}: episode reward {f['reward']:.0f}")
        bx.step(t[:-1], elevator + 0.08 * (i - 1), where="post", lw=1.0, label=name)
    ax.axhline(0, color="k", lw=0.6)
    ax.set_ylabel("altitude error h - h_d (ft)")
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    bx.set_yticks([-1, 0, 1], ["-1 (nose up)", "0", "+1 (nose down)"])
    bx.set_ylabel("elevator (lines offset to show overlaps)")
    bx.set_xlabel("time (s)")
    bx.grid(alpha=0.3)
    ax.set_title(f"one episode after training{f' ({label})' if label else ''}, the same noise for all", fontsize=9)
    return save(fig, out / "f16_trace.png", title)


# ------------------------------------------------------------ figures (scripts/plot.py)
SCRIPTED = ("pd", "lqr", "constant", "random")  # no learning: drawn as their mean


def blocks(df: pd.DataFrame, block: int) -> pd.DataFrame:
    """Per block of ``block`` episodes: the median and quartiles across seeds of each
    seed's mean reward in it; indexed by the block's middle episode."""
    b = (df["episode"] - 1) // block
    per_seed = df.groupby([b, df["seed"]])["return"].mean()
    g = per_seed.groupby(level=0)
    out = pd.DataFrame({"median": g.median(), "q25": g.quantile(0.25), "q75": g.quantile(0.75)})
    out.index = out.index * block + (block + 1) / 2  # the block's middle episode
    return out


def reward_figure(runs, labels, out: Path, block: int = 10, title: str = "") -> Path:
    """f16_reward.png: the learners' episode reward (median and IQR across seeds of each
    block's mean), the scripted agents' mean as lines, and GWH14's Figure 3 as marks."""
    import matplotlib.pyplot as plt

    from trl_dgpq.analysis.figures import log_axis, save
    fig, ax = plt.subplots(figsize=(7.0, 4.4))
    scripted, marked = [], set()
    for run, label in zip(runs, labels):
        df = run.df
        if run.agent in SCRIPTED:
            styles = [(":", "k"), ("--", "0.4"), ("-.", "0.6"), (":", "0.7")]
            ls, color = styles[len(scripted) % len(styles)]
            scripted.append(ax.axhline(df["return"].mean(), ls=ls, color=color, lw=1.0,
                                       label=f"{label} (mean {df['return'].mean():.0f})"))
            continue
        b = blocks(df, block)
        line, = ax.plot(b.index, b["median"], lw=1.2, label=f"{label} ({df.seed.nunique()} seeds)")
        ax.fill_between(b.index, b["q25"], b["q75"], color=line.get_color(), alpha=0.25, lw=0)
        lipschitz = run.config["agent"].get("lipschitz") if run.agent == "dgpq" else None
        marks = PAPER.get(lipschitz) if lipschitz not in marked else None  # once per L_Q, in its first run's colour
        marked.add(lipschitz)
        if marks:
            (e0, r0), (e1, r1) = marks
            ax.plot([e0], [r0], "x", color=line.get_color(), ms=8)
            ax.plot([e1 - 50, e1 + 50], [r1, r1], lw=3, color=line.get_color(), alpha=0.6)
    ax.plot([], [], "kx", label="GWH14 Fig. 3: start (x) and episodes 100-200 / 900-1000 (bar)")
    log_axis(ax, integer=True, axis="x")
    ax.set_xlabel(f"episode (log axis; blocks of {block})")
    ax.set_ylabel("episode reward (median of seeds; band: IQR)")
    ax.set_title("F-16 altitude hold: episode reward per block of episodes", fontsize=10)
    ax.grid(alpha=0.3, which="both")
    ax.legend(fontsize=7, loc="lower right", ncol=2)
    return save(fig, out / "f16_reward.png", title)


def figures(runs, labels, out: Path, block: int = 10, last=None, title: str = "", **_) -> list:
    """f16_reward.png, and f16_trace.png for the first learner with a checkpoint."""
    written = [reward_figure(runs, labels, out, block=block, title=title)]
    from trl_dgpq.collectors.evaluate import job_folders
    learner = next(((r, l) for r, l in zip(runs, labels) if r.agent not in SCRIPTED and job_folders(r.path)), None)
    folder, label = (learner[0].path, learner[1]) if learner else (None, "")
    trace = trace_figure(folder, out, title, label=label)     # without a checkpoint: from what was drawn, if kept
    return written + ([trace] if trace else [])


# ------------------------------------------------------------ the reproduction (scripts/reproduce.py)
TITLE = "Aircraft altitude hold (GWH14's second experiment)"
# experiments reproduced apart: each its own `reproduce --only` name, section and claims ("module" or
# "module:object" of this folder, with REPRODUCE, SCALES, CLAIMS and declared_claims(), TITLE, SUMMARY and
# reproduce_section, as here)
APART = {"f16-model": "model_ablation:FLIGHT_05", "f16-model-gwh14": "model_ablation:GWH14"}
# the README's paragraph on the domain: words, no numbers (those come from the data)
SUMMARY = ("DGPQ at L_Q 5 and 10 and DQN in GWH14's formulation (a decision every 0.05 s), the same deciding "
           "every 0.5 s (`flight-05`), and two variants that shape the reward by the LQR's value of the "
           'linearised model (they use the model: counted apart), beside doing nothing, PD, the LQR and a random'
           ' elevator.')
# quick: 2 seeds x 10 episodes, a check that each runs (at 4 x 100 the F-16 alone took ~15 of quick's
# ~28 minutes on 2 loaded cores, issue 30; 20 episodes and 30 for gamma 0.99 took 1.5 of 9.4 quiet, issue 53)
SCALES = {"smoke": (1, 3), "quick": (2, 10), "full": (10, 1000), "report": (10, 1000)}
SCRIPTED_SCALES = {k: (seeds, min(episodes, 100)) for k, (seeds, episodes) in SCALES.items()}
REPRODUCE = [
    ("f16-dgpq-lq5", dict(agent="dgpq", preset="default")),
    ("f16-dgpq-lq10", dict(agent="dgpq", preset="lq10")),
    ("f16-dgpq-gamma99", dict(agent="dgpq", preset="gamma99"),
     {"smoke": (1, 2), "quick": (1, 10), "full": (4, 300), "report": (4, 300)}),  # Q̂ grows: ~1 ms per step
    ("f16-dqn", dict(agent="dqn", preset="default")),
    ("f16-pd", dict(agent="pd", preset="default"), SCRIPTED_SCALES),
    ("f16-lqr", dict(agent="lqr", preset="default"), SCRIPTED_SCALES),
    ("f16-nothing", dict(agent="constant", preset="default"), SCRIPTED_SCALES),
    ("f16-random", dict(agent="random", preset="default"), SCRIPTED_SCALES),
]
# The "flight-05" formulation (a decision every 0.5 s), where DGPQ beats holding in time.
# These parts exist for their claims, which 50 episodes cannot decide: no quick scale.
FLIGHT_SCALES = {"smoke": (1, 3), "full": (10, 1500), "report": (10, 3000)}
FLIGHT_SCRIPTED = {k: (seeds, min(episodes, 100)) for k, (seeds, episodes) in FLIGHT_SCALES.items()}
REPRODUCE += [
    ("f16-05-dgpq-lq5", dict(agent="dgpq", preset="flight-05"), FLIGHT_SCALES),
    ("f16-05-dgpq-lq10", dict(agent="dgpq", preset="flight-05", lipschitz=10.0), FLIGHT_SCALES),
    ("f16-05-dqn", dict(agent="dqn", preset="flight-05"), FLIGHT_SCALES),
    ("f16-05-pd", dict(agent="pd", preset="flight-05"), FLIGHT_SCRIPTED),
    ("f16-05-nothing", dict(agent="constant", preset="flight-05"), FLIGHT_SCRIPTED),
]
# flight-05 shaped by the LQR's potential (uses the model), where DGPQ flies: GWH14's 1,000 episodes.
SHAPED_SCALES = {"smoke": (1, 3), "full": (10, 1000), "report": (10, 1000)}
REPRODUCE += [
    ("f16-shaped-dgpq-lq5", dict(agent="dgpq", preset="flight-05-shaped"), SHAPED_SCALES),
    ("f16-shaped-dgpq-lq10", dict(agent="dgpq", preset="flight-05-shaped", lipschitz=10.0), SHAPED_SCALES),
    ("f16-shaped-dqn", dict(agent="dqn", preset="flight-05-shaped"), SHAPED_SCALES),
    ("f16-shaped-dqn-tuned", dict(agent="dqn", preset="flight-05-shaped-tuned"), SHAPED_SCALES),
]
# GWH14's own formulation (0.05 s per decision) at gamma 0.99, shaped by the LQR's potential: Figure 3's marks.
REPRODUCE += [
    ("f16-g99-dgpq-lq5", dict(agent="dgpq", preset="gamma99-shaped"), SHAPED_SCALES),
    ("f16-g99-dgpq-lq10", dict(agent="dgpq", preset="gamma99-shaped", lipschitz=10.0), SHAPED_SCALES),
    ("f16-g99-dqn", dict(agent="dqn", preset="gamma99-shaped"), SHAPED_SCALES),
]


def late_window(E: int) -> tuple:
    """The episodes the "late" column averages: GWH14's 900-1000 when the run got there, else
    its last 10 (never the whole run)."""
    return (901, 1000) if E >= 1000 else (max(1, E - 9), E)


def row(name: str, df: pd.DataFrame, late=None) -> tuple:
    E = int(df.episode.max())
    stable = episodes_to_stable(df)
    late = late or late_window(E)
    cells = (f"{window_reward(df, 1, 10):.0f}",
             f"{window_reward(df, 100, 200):.0f}" if E >= 200 else "- (not run to 200)",  # GWH14's window, whole
             f"{window_reward(df, *late):.0f} ({late[0]}-{late[1]})",
             f"{stable.notna().sum()} of {len(stable)}" + (f", median {stable.median():.0f}" if stable.notna().any()
                                                           else ""),
             f"{ms_per_seed_step(df):.2f}")
    return f"| {name.removeprefix('f16-')} | {df.seed.nunique()} x {E} | " + " | ".join(cells) + " |"


TABLE_HEAD = ["| agent | seeds x episodes | episode reward, episodes 1-10 (mean over seed-episodes) | 100-200 (mean) "
              "| late (episodes; mean) | seeds flying stably (median first episode) | ms per seed-step |",
              "|---|---|---|---|---|---|---|"]


PARTS = {  # name prefix: (folder, heading, the figure's block and preset)
    "f16-05-": ("f16-05", "A decision every 0.5 s (`flight-05`)", 50, "flight-05"),
    "f16-shaped-": ("f16-shaped", "Shaped by the LQR's potential (`flight-05-shaped`; uses the model)", 10, "flight-05-shaped"),
    "f16-g99-": ("f16-g99", "GWH14's formulation at γ 0.99, shaped by the LQR's potential (`gamma99-shaped`; uses the model)",
                 10, "gamma99-shaped"),
}


def part(prefix: str, runs: dict, out: Path, title: str) -> str:
    """A variant's runs' table and figure: "late" is each run's last 100 episodes."""
    folder, heading, block, preset = PARTS[prefix]
    (out / folder).mkdir(exist_ok=True)
    names = list(runs)
    reward_figure([runs[n] for n in names], [n.removeprefix(prefix) for n in names], out / folder,
                  block=block, title=f"{preset}, {title}")
    rows = [row(n, runs[n].df, late=(max(1, runs[n].df.episode.max() - 99), runs[n].df.episode.max()))
            for n in names]
    return (f"### {heading}\n\n" + "\n".join(TABLE_HEAD + rows)
            + f"\n\n![reward, {folder}]({folder}/f16_reward.png)\n")


def reference(name: str):
    """Per seed: the mean episode reward of a scripted reference over every episode it ran (its
    value does not change with the episode)."""
    return lambda runs: seed_means(runs[name].df, "return")


def rewards(name: str, first=None, last=None):
    """Per seed: the mean episode reward of run ``name`` over episodes ``first``..``last`` (None: its
    last 100); an error if it did not run that far."""
    def per_seed(runs):
        df = runs[name].df
        E = int(df.episode.max())
        lo, hi = (first, last) if first is not None else (max(1, E - 99), E)
        if hi > E:
            raise ValueError(f"{name} ran {E} episodes, not to episode {hi}")
        return seed_means(df, "return", lo, hi)
    return per_seed


def interval_of(per_seed):
    def measure(runs):
        from trl_dgpq.analysis.claims import seeds_interval
        return seeds_interval(per_seed(runs))
    return measure


def stable_by(name: str, episode: int):
    """The claim's measure: the share of seeds whose 10-episode mean met THRESHOLD by ``episode``."""
    def measure(runs):
        from trl_dgpq.analysis.claims import share_interval
        df = runs[name].df
        if df.episode.max() < episode:
            raise ValueError(f"{name} ran {df.episode.max()} episodes, not to episode {episode}")
        stable = episodes_to_stable(df)
        return share_interval(int((stable <= episode).sum()), len(stable), f"flying stably by episode {episode}")
    return measure


def of_pd(name: str, first: int, last: int, hold: str, pd_run: str, progress: bool):
    """The claim's measure, per seed over episodes first..last: with ``progress``, how far from doing
    nothing to PD the learner got (0: holding, 1: PD); else its reward as a multiple of PD's (both
    negative: 1.1 is 10 % worse). The references' means are over every seed-episode they ran."""
    def measure(runs):
        from trl_dgpq.analysis.claims import seeds_interval
        ours = rewards(name, first, last)(runs)
        pd_mean = float(runs[pd_run].df["return"].mean())
        hold_mean = float(runs[hold].df["return"].mean())
        return seeds_interval((ours - hold_mean) / (pd_mean - hold_mean) if progress else ours / pd_mean)
    return measure


def declared_claims() -> list:
    """GWH14's Figure 3 (two marks and stable flight per L_Q), in GWH14's formulation and, a variant
    using the model, at gamma 0.99 shaped by the LQR's potential; deciding every 0.5 s, that DGPQ
    beats doing nothing; shaped by the LQR's potential, the suite's goal of flying near PD."""
    from trl_dgpq.analysis.claims import Agrees, Beats, Bound, Claim
    out = []
    for prefix, where in (("f16-", "GWH14's formulation"),
                          ("f16-g99-", "GWH14's formulation at gamma 0.99, shaped by the LQR's potential "
                                       "(`gamma99-shaped`)")):
        for L, name in ((5, f"{prefix}dgpq-lq5"), (10, f"{prefix}dgpq-lq10")):
            (_, first), (e1, mark) = PAPER[float(L)]
            lo, hi = (100, 200) if e1 < 500 else (900, 1000)
            by = 100 if L == 5 else 1000
            key = f"f16/{prefix.strip('-').replace('f16', 'gwh14')}/lq{L}"
            base = "f16-nothing"
            out += [Claim(f"{key}/reward", "GWH14", f"DGPQ at L_Q {L}: episode reward about {first} at first, {mark} "
                          f"by episodes {lo}-{hi} (each seed's mean there); run in {where}",
                          Agrees(mark, 1.5, higher_is_better=True), interval_of(rewards(name, lo, hi)), (name,),
                          baseline=base, baseline_measure=interval_of(reference(base)), fmt="{:.1f}"),
                    Claim(f"{key}/stable", "GWH14", f"DGPQ at L_Q {L} flies stably "
                          f"{'within 100 episodes' if L == 5 else 'by about 1,000 episodes'} (read: the share of seeds "
                          f"whose 10-episode mean came within 10 % of PD by episode {by:,} is above half); run in "
                          f"{where}",
                          Bound(0.5, higher_is_better=True), stable_by(name, by), (name,), fmt="{:.2f}")]
    out.append(Claim("f16/flight-05/beats-holding", "this suite", "deciding every 0.5 s (`flight-05`), DGPQ at L_Q 5 "
                     "beats doing nothing over its last 100 episodes (of 3,000)", Beats(higher_is_better=True),
                     interval_of(rewards("f16-05-dgpq-lq5")), ("f16-05-dgpq-lq5",), baseline="f16-05-nothing",
                     baseline_measure=interval_of(reference("f16-05-nothing")), decided_at=("report",),
                     fmt="{:.1f}"))
    shaped = "f16-shaped-dgpq-lq5", "f16-05-nothing", "f16-05-pd"
    out += [Claim("f16/flight-05-shaped/halfway", "this suite", "shaped by the LQR's potential (`flight-05-shaped`), "
                  "DGPQ at L_Q 5 is past halfway from doing nothing (0) to PD (1) by episodes 91-100",
                  Bound(0.5, higher_is_better=True), of_pd(shaped[0], 91, 100, *shaped[1:], progress=True), shaped,
                  fmt="{:.2f}"),
            Claim("f16/flight-05-shaped/near-pd", "this suite", "shaped by the LQR's potential (`flight-05-shaped`), "
                  "DGPQ at L_Q 5 is within 10 % of PD by episodes 191-200 (its reward as a multiple of PD's)",
                  Bound(1.1, higher_is_better=False), of_pd(shaped[0], 191, 200, *shaped[1:], progress=False),
                  shaped, fmt="{:.3f}")]
    return out


CLAIMS = declared_claims()


def reproduce_section(runs: dict, out: Path, label: str, title: str, judged: list) -> str:
    """REPORT.md's F-16 section; ``runs``: {name in REPRODUCE: Run}; ``judged``: the verdicts of ``CLAIMS``."""
    (out / "f16").mkdir(exist_ok=True)
    variants = {p: {n: r for n, r in runs.items() if n.startswith(p)} for p in PARTS}
    gwh14 = {n: r for n, r in runs.items() if not any(n.startswith(p) for p in PARTS)}
    names = list(gwh14)
    figures([gwh14[n] for n in names], [n.removeprefix("f16-") for n in names], out / "f16",
            block=10, title=title)
    rows = TABLE_HEAD + [row(n, gwh14[n].df) for n in names]
    sentences = [j.bullet() for j in judged]
    return (f"## Aircraft altitude hold (GWH14's second experiment) -- Figure 3\n\n{label}\n\n"
            + "\n".join(rows) + "\n\n" + "\n".join(sentences)
            + "\n\n![reward](f16/f16_reward.png)" + (" ![trace](f16/f16_trace.png)" if (out / "f16" / "f16_trace.png")
                                                      .is_file() else "") + "\n"
            + "".join("\n" + part(p, v, out, title) for p, v in variants.items() if v))


# ------------------------------------------------------------ is Q̂ still optimistic? (issue 28)
# DGPQ's guarantee rests on Q̂ staying above Q* (less ε): an action whose Q̂ falls below its
# value is never tried again, since Q̂ only ever decreases. Q of "take a, then fly the quantised
# LQR" is a lower bound on Q* (the LQR is one policy), so Q̂(s, a) below it by more than ε₁ is
# optimism lost, measurably.
def lqr_q(cfg, states, gamma: float, rollouts: int = 100, r: float = 0.1, seed: int = 0,
          tol: float = 1e-3):
    """(N, 3) Q of each elevator setting at each of ``states`` (N, 5) (the env's units), then
    the quantised LQR (weight ``r``): the mean discounted reward of ``rollouts`` flights through
    the env itself (its dynamics, noise and reward; the same noise for the three settings),
    until γ^t < ``tol``. A flight that leaves the envelope earns nothing after its penalty."""
    from dataclasses import replace

    import torch
    from tensordict import TensorDict

    from .baselines import LQRConfig, LQRPolicy
    from .env import F16Env
    from .potential import horizon as decisions_until

    horizon = decisions_until(gamma, tol)
    n, m = len(states), rollouts
    seeds = list(range(seed, seed + n * m))      # the same streams for each setting: common noise
    long = replace(cfg, max_steps=horizon, potential="none")   # the leaving penalty counts the steps left
    q = torch.zeros(n, 3, dtype=torch.float64)
    for a in range(3):
        env = F16Env(seeds, long)
        env.reset()
        env.state.copy_(torch.as_tensor(states, dtype=torch.float64).repeat_interleave(m, 0))
        lqr = LQRPolicy.make(LQRConfig(r=r), env.info, seeds)
        action = torch.full((n * m,), a, dtype=torch.long)
        total = torch.zeros(n * m, dtype=torch.float64)
        alive = torch.ones(n * m, dtype=torch.bool)
        for t in range(horizon):
            nxt = env.step(TensorDict(action=action, batch_size=[n * m]))["next"]
            total += alive * gamma ** t * nxt["reward"].reshape(-1)
            alive &= ~nxt["terminated"].reshape(-1)
            action = lqr.act(nxt)
        q[:, a] = total.view(n, m).mean(1)
    return q


def visited(cfg, policy: str, episodes: int, seed: int = 0):
    """The states (episodes * max_steps, 5) that ``policy`` ("hold" or "lqr") flies through
    from the env's start, one episode per seed row (each seed's own noise)."""
    from dataclasses import replace

    import torch
    from tensordict import TensorDict

    from .baselines import LQRConfig, LQRPolicy
    from .env import F16Env

    seeds = list(range(seed, seed + episodes))
    env = F16Env(seeds, replace(cfg, potential="none"))
    td = env.reset()
    lqr = LQRPolicy.make(LQRConfig(r=0.1), env.info, seeds)
    out = []
    for _ in range(cfg.max_steps):
        out.append(td["state"].clone())
        action = lqr.act(td) if policy == "lqr" else torch.ones(episodes, dtype=torch.long)
        td = env.step(TensorDict(action=action, state=td["state"], batch_size=[episodes]))["next"]
    return torch.cat(out)


def optimism(folder: Path, on: str = "hold", episodes: int = 8, rollouts: int = 100) -> pd.DataFrame:
    """Per seed of the DGPQ run in ``folder``: at the states ``on`` ("hold" or "lqr") flies
    through (seeds 9000+, episodes the run never saw), the share of states where Q̂(s, a) is
    below Q of a-then-LQR less ε₁ (optimism lost), the median shortfall there, Q̂'s greedy
    action against the LQR-continuation's best (counts of nose-up, hold, nose-down; ``pulse_gap``:
    the median margin by which a pulse is best where it is), and Q̂
    and Q at the start state; ``attrs["slopes"]``: ``slopes`` at those states. In a run shaped by
    a potential Φ, Q is Q − Φ throughout (what its Q̂ bounds)."""
    import torch

    from trl_dgpq.collectors.evaluate import jobs, restore
    config, env, agent, _ = restore(jobs(folder)[0])
    if not hasattr(agent, "qhat"):
        raise ValueError(f"{folder} is not a DGPQ run (its agent has no Q̂)")
    states = visited(env.cfg, on, episodes, seed=9000)
    q = lqr_q(env.cfg, states, agent.cfg.gamma, rollouts)
    if env.potential is not None:   # a shaped run's Q̂ is an envelope of Q − Φ (shaping telescopes)
        q = q - env.potential(states)[:, None]
    f = agent.features(env.observation(states))
    qhat = torch.stack([agent.qhat(x[None].expand(agent.S, -1)) for x in f])    # (N, S, A)
    top = q.sort(1, descending=True).values
    pulse = q.argmax(1) != 1
    gap = float((top[:, 0] - top[:, 1])[pulse].median()) if pulse.any() else float("nan")
    rows = []
    for i, seed in enumerate(config["run"]["seeds"]):
        below = qhat[:, i] < q - agent.cfg.eps1
        short = (q - qhat[:, i])[below]
        rows.append(dict(seed=seed, L_Q=agent.cfg.lipschitz,
                         **{f"below_{n}": float(below[:, a].double().mean()) for a, n in enumerate(("up", "hold", "down"))},
                         median_shortfall=float(short.median()) if len(short) else 0.0,
                         greedy=torch.bincount(qhat[:, i].argmax(1), minlength=3).tolist(),
                         lqr_best=torch.bincount(q.argmax(1), minlength=3).tolist(), pulse_gap=gap,
                         qhat_start=[round(v, 1) for v in qhat[0, i].tolist()],
                         q_start=[round(v, 1) for v in q[0].tolist()],
                         qhat_pairs=int(agent.qhat.size()[i])))
    df = pd.DataFrame(rows)
    df.attrs["slopes"] = slopes(f, q)   # how steep Q is there, per unit of the run's metric
    return df


def slopes(features, q, min_distance: float = 0.05) -> pd.DataFrame:
    """How steep Q is in DGPQ's metric: for each action, quantiles over pairs of states (their
    ``features``, L1 distance above ``min_distance``) of |Q(s, a) - Q(s', a)| / d(s, s'). Q̂ stays
    an upper envelope only while L_Q is at least the largest of these."""
    import torch
    d = torch.cdist(features, features, p=1)
    far = d > min_distance
    rows = {}
    for a, name in enumerate(("up", "hold", "down")):
        slope = ((q[:, a, None] - q[None, :, a]).abs()[far] / d[far])
        rows[name] = {k: float(slope.quantile(v)) if k != "max" else float(slope.max())
                      for k, v in (("median", 0.5), ("90%", 0.9), ("99%", 0.99), ("max", 1.0))}
    return pd.DataFrame(rows).T


if __name__ == "__main__":   # python -m trl_dgpq.envs.f16.analysis RUN [hold|lqr]
    import sys
    pd.set_option("display.width", 250)
    on = (sys.argv[2:3] or ["hold"])[0]
    got = optimism(Path(sys.argv[1]), on)
    print(f"Q of a-then-LQR along {on}'s flights: its slope per unit of the run's metric\n"
          f"{got.attrs['slopes'].round(1).to_string()}")
    print(got.to_string(index=False))
