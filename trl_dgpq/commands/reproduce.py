"""Reproduce every experiment of the seed report as one sweep, then its figures and REPORT.md.

    python scripts/reproduce.py                    # --scale quick (docs/reproducing.md: times)
    python scripts/reproduce.py --scale full       # 1,000 liquidation episodes, 100 on the square and push
    python scripts/reproduce.py --scale report     # the seed report's own lengths: liquidation 11,000
                                                   # episodes, DDPG at gamma 0.01 too (many hours: run it
                                                   # in parts, each call continues where the last stopped)
    python scripts/reproduce.py --out runs/repro   # run it again: continues what did not finish
    python scripts/reproduce.py --only f16         # one domain's experiments and section
    python scripts/reproduce.py --scale report --only liquidation --experiments 'liq-dgpq-*'   # some of them
                                                   # now, the rest in a later call
    python scripts/reproduce.py --scale report --publish results/report   # what the repository keeps: the
                                                   # per-episode data, and every file rebuilt from them
    python scripts/reproduce.py --scale report --report   # run nothing: the report of what has finished so far

Each domain with a reproduction (``REPRODUCE``, ``SCALES`` and ``reproduce_section`` in
``envs/<domain>/analysis.py``: the square's presets and kernels, Figures 2-4; block
pushing, Figure 5; liquidation's agents at both discounts, the course's own DDPG, Figures
6-7) contributes its
experiments to one sweep (``collectors/sweep.py``: a pool of worker processes, each
experiment one job) and a section to REPORT.md, which sets our numbers beside the seed
report's claims and GWH14's (``claims`` in the same file: REPORT.md's first table, each with a
verdict). The quick scale
runs fewer seeds and episodes and says so in every title and table.
"""
from __future__ import annotations

import argparse
import fnmatch
import json
import math
import os
import re
import sys
import time
from collections import Counter
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Dict, List, Optional

from trl_dgpq.analysis import count, load_run, ms_per_seed_step
from trl_dgpq.collectors import runner, sweep
from trl_dgpq.collectors.experiment import resolve_config
from trl_dgpq.commands import prog
from trl_dgpq.envs import domains
from trl_dgpq.selection import FIRST_REPORTING

SCALES = ("smoke", "quick", "full", "report")  # smoke: for tests; report: the seed report's own lengths


@dataclass(frozen=True)
class Part:
    """One section of the reproduction and its ``--only`` name: a domain's analysis, or an experiment
    of that domain reproduced apart (its analysis' ``APART``: {name: "module" or "module:object" of its
    folder})."""
    name: str
    domain: object

    def examples(self) -> tuple:
        return self.domain.examples()


def reproductions(only=None) -> list:
    """[(part, module)]: every domain with a reproduction, each followed by its experiments apart (or
    the parts named in ``only``), in registry order."""
    found = []
    for d in domains():
        analysis = d.analysis()
        found.append((Part(d.name, d), analysis))
        for name, where in getattr(analysis, "APART", {}).items():
            module, _, attr = where.partition(":")
            found.append((Part(name, d), getattr(d.module(module), attr) if attr else d.module(module)))
    return [(part, a) for part, a in found if hasattr(a, "REPRODUCE") and (not only or part.name in only)]


def same_run(config: dict) -> dict:
    """A config's run section with today's defaults for settings added since it was recorded,
    so that a sweep begun by an older version still counts as this one."""
    from trl_dgpq.collectors.experiment import RunConfig
    from trl_dgpq.config import from_dict, to_dict
    return to_dict(from_dict(RunConfig, config["run"]))


def same_config(config: dict) -> dict:
    """The whole config, each section with today's defaults for settings added since it was
    recorded (as ``same_run``): what another sweep's experiment must equal for its rows to be
    taken as this one's (every env and agent setting included)."""
    from trl_dgpq.collectors.experiment import load_sections
    from trl_dgpq.config import to_dict
    run, env, agent = load_sections(config)
    return {**config, "run": to_dict(run), "env": to_dict(env), "agent": to_dict(agent)}


def same_sections(recorded: dict) -> dict:
    """``same_config`` of a recorded config's run, env and agent sections alone (it also holds the
    git, jobs and versions it ran with)."""
    return same_config({k: recorded[k] for k in ("run", "env", "agent")})


def plan_settings(scale: str, only=None) -> dict:
    """{experiment name: its settings as given} at ``scale`` (env, agent, preset, seeds, episodes,
    env_steps and the experiment's own settings): what ``experiments`` resolves and ``--sweep-file``
    writes. An experiment runs at the scales its sizes name: one that only decides claims is left out
    of the scales too small to decide them."""
    every = reproductions()
    unknown = sorted(set(only or ()) - {part.name for part, _ in every})
    if unknown:
        raise ValueError(f"no part named {', '.join(unknown)}; the parts: " + ", ".join(part.name for part, _ in every))
    out = {}
    for d, analysis in (every if not only else [(p, a) for p, a in every if p.name in only]):
        for name, settings, *own in analysis.REPRODUCE:
            sizes = (own[0] if own else analysis.SCALES).get(scale)
            if sizes is None:  # an experiment of some scales only
                continue
            seeds, episodes, *budget = sizes   # (seeds, episodes[, env steps per seed])
            first = getattr(analysis, "FIRST_SEED", FIRST_REPORTING)   # past the seeds development explored
            out[name] = {"env": d.examples()[0], **settings, "seeds": list(range(first, first + seeds)),
                         "episodes": episodes, "env_steps": budget[0] if budget else 0}
    return out


def experiments(scale: str, only=None) -> dict:
    """{experiment name: resolved config} at ``scale`` (``plan_settings`` resolved)."""
    return {name: resolve_config(settings) for name, settings in plan_settings(scale, only).items()}


def toml_value(value) -> str:
    """A setting as TOML writes it (strings, numbers, booleans and lists of them are all a plan holds)."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, (int, float)):
        return repr(value)
    if isinstance(value, str):
        return json.dumps(value)      # a JSON string is a TOML basic string
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(toml_value(v) for v in value) + "]"
    raise TypeError(f"a sweep file cannot hold {value!r}")


def sweep_file(settings: dict, command: str) -> str:
    """The planned experiments as a sweep file (``trl-dgpq sweep FILE``): each experiment's run
    settings at the top, its env and agent settings under ``[experiment.set]``; the same configs as
    the plan (tests/test_reproduce_plan.py reads it back)."""
    from trl_dgpq.analysis.results import seeds_text
    from trl_dgpq.collectors.experiment import RunConfig
    from trl_dgpq.config import leaves
    run_keys = {leaf.key for leaf in leaves(RunConfig)}
    def toml_key(k: str) -> str:   # a dotted path is one key, not nested tables
        return k if re.fullmatch(r"[A-Za-z0-9_-]+", k) else json.dumps(k)
    lines = [f"# Written by `{command}`:", "# that plan as a sweep, the same configs (`trl-dgpq sweep THIS_FILE --out "
             "DIR` runs it;", "# REPORT.md and the claims come from reproduce, which runs the same experiments)."]
    for name, given in settings.items():
        lines += ["", "[[experiment]]", f"name = {toml_value(name)}"]
        rest = {}
        for key, value in given.items():
            if key == "seeds":         # as --seeds reads it back ("A-B", "N-N" for one seed)
                lines.append(f"seeds = {toml_value(seeds_text(value))}")
            elif key in run_keys:
                lines.append(f"{key} = {toml_value(value)}")
            else:
                rest[key] = value
        if rest:
            lines.append("[experiment.set]")
            lines += [f"{toml_key(k)} = {toml_value(v)}" for k, v in rest.items()]
    return "\n".join(lines) + "\n"


def in_order(jobs: list, workers: int, cost=None) -> list:
    """The order the jobs run in. On one worker, domain by domain, the domain of fewest planned
    seed-steps first and its jobs shortest first: a run of many hours completes a section of
    the report (``--report``) as early as it can. On more, the longest first by ``cost`` (job ->
    its estimated seconds, ``job_cost``), so that no long job starts last: the schedule the plan's
    wall time assumes; without a cost, DDPG and TD3 first (on liquidation ~0.5 and ~8 ms per
    seed-step against DGPQ's ~0.2)."""
    if workers > 1:
        if cost is not None:
            return sorted(jobs, key=lambda j: -cost(j))   # stable: ties keep the plan's order
        return sorted(jobs, key=lambda j: j.config["run"]["agent"] not in ("ddpg", "td3"))
    domain_of = {name: d.name for d, analysis in reproductions() for name, *_ in analysis.REPRODUCE}
    steps = [sweep.planned_seed_steps(j) for j in jobs]
    per_domain = Counter()
    for j, n in zip(jobs, steps):
        per_domain[domain_of[j.experiment]] += n
    order = sorted(range(len(jobs)), key=lambda i: (per_domain[domain_of[jobs[i].experiment]], steps[i]))
    return [jobs[i] for i in order]


def scale_label(scale: str, only=None) -> str:
    note = (f"fewer seeds and episodes than the seed report (the {scale} scale; numbers are noisier)"
            if scale not in ("full", "report") else "the seed report's lengths")
    sizes = []
    for d, a in reproductions(only):
        seeds, length, *budget = a.SCALES[scale]
        if budget:   # env steps per seed: a number, or a range as text ("20,000-120,000")
            length = f"{budget[0]:,} env steps" if isinstance(budget[0], int) else f"{budget[0]} env steps"
        else:
            length = count(length, "episode")
        sizes.append(f"{d.name} {count(seeds, 'seed')} x {length}")
    return f"*Scale: {scale}* -- {note}: " + ", ".join(sizes) + " (some agents fewer: see the tables)."


def finished(out: Path, name: str) -> bool:
    """Whether an experiment of the sweep in ``out`` has finished (its jobs' rows merged)."""
    return (out / name / runner.EPISODES).is_file()


def runs_of(out: Path, scale: str, wall: float, only, command: str) -> tuple:
    """(planned {name: config}, finished names, load(name) -> Run, the report's head) of ``out``: a
    sweep's folder, or a publication (``analysis/published.py``), whose runs are its data, checked
    for the seeds they may be published on, and whose head names the publication."""
    from trl_dgpq.analysis import published
    if not published.is_published(out):
        prov = runner.provenance()
        planned = experiments(scale, only)
        head = (f"# Reproduction of the seed report ({scale} scale)\n\nGenerated by `{command}` on "
                f"{time.strftime('%Y-%m-%d %H:%M')}, commit {prov['git']['commit']}"
                f"{' (dirty)' if prov['git']['dirty'] else ''}, {os.cpu_count()} cores; sweep wall time "
                f"{wall / 60:.1f} min (this invocation).\n\n")
        return planned, [n for n in planned if finished(out, n)], lambda name: load_run(out / name), head
    from trl_dgpq.selection import check_reportable
    stamp = published.manifest(out)
    kept = {name: published.load(out, name) for name in stamp["experiments"]}
    for name, run in kept.items():     # the seeds of its config and of its rows
        seeds = sorted(set(run.config["run"]["seeds"]) | {int(s) for s in run.df["seed"].unique()})
        check_reportable({**run.config, "run": {**run.config["run"], "seeds": seeds}}, name, publication=True)
    planned = {name: kept[name].config if name in kept else None for name in stamp.get("planned", kept)}
    head = (f"# Reproduction of the seed report ({scale} scale)\n\nBuilt from the per-episode data in "
            f"`data/` by `trl-dgpq report` on this folder: the runs of `{stamp['command']}`, published "
            f"{stamp['published']} at commit {stamp['commit']}{' (dirty)' if stamp['dirty'] else ''}"
            + "".join(f"; those of {', '.join(k['parts'])} ({count(len(k['experiments']), 'experiment')}) as "
                      f"`{k['command']}` published them on {k['published']} at commit {k['commit']}"
                      f"{' (dirty)' if k['dirty'] else ''}, kept unchanged" for k in stamp.get("kept", []))
            + ". Every "
            "number and figure below is computed from those files (a trained agent's figures from what its "
            "checkpoint showed, kept beside them: Q̂ over the square, the F-16's trace, liquidation's holdings), "
            "but the push animation, kept as drawn at the run.\n\n")
    return planned, list(kept), kept.__getitem__, head


def write_report(out: Path, scale: str, wall: float, only=None) -> Path:
    """REPORT.md, claims.md, results.csv, summary.md and sections/ from the experiments of ``out``
    that have finished (``runs_of``): a domain's section and claims once all its experiments have,
    else a line saying how far it got (a report of a run still going, or stopped: ``--report``)."""
    from trl_dgpq.analysis.claims import judge, table
    command = f"python scripts/reproduce.py --scale {scale}" + (" --only " + " ".join(only) if only else "")
    planned, done, load, head = runs_of(out, scale, wall, only, command)
    if len(done) < len(planned):
        head += (f"**Partial: {len(done)} of {len(planned)} experiments have finished.** A domain's section and "
                 "claims appear once all its experiments have; the run continues with the same command.\n\n")
    title = f"{scale} scale" + (" (fewer seeds and episodes than the seed report)"
                                if scale not in ("full", "report") else "")
    loaded, sections, judged, summaries, shown = [], [], [], [], []
    (out / "sections").mkdir(exist_ok=True)
    for old in (out / "sections").glob("*.md"):
        old.unlink()
    for d, analysis in reproductions(only):
        names = [name for name, *_ in analysis.REPRODUCE if name in planned]
        if not names:
            continue
        runs = {name: load(name) for name in names if name in done}
        loaded.append((analysis, runs))
        if len(runs) < len(names):
            sections.append(f"## {d.name}: not finished\n\n{len(runs)} of {len(names)} experiments have finished; "
                            f"waiting for {', '.join(n for n in names if n not in runs)}.\n")
            continue
        mine = [judge(c, runs, scale, planned) for c in getattr(analysis, "CLAIMS", [])]
        section = analysis.reproduce_section(runs, out, scale_label(scale, only), title, mine)
        # the docs site's include of this section (mkdocs.yml: a page under docs/domains/ includes it)
        (out / "sections" / f"{d.name}.md").write_text(section.replace("](", "](../results/"))
        sections.append(section)
        judged += mine
        summaries.append(domain_summary(d, analysis, mine))
        shown.append(d.name)
    for d, _ in reproductions():   # the docs include every domain's section: say where one is not here
        if d.name not in shown:
            (out / "sections" / f"{d.name}.md").write_text(
                f"*{d.name}: not in this report (`{command}`): its experiments have not all finished, or it was "
                "not among the domains run.*\n")
    summary = ("## Claims, and whether they reproduce\n\nEach claim of GWH14, the seed report, AC00 (the model's "
               "closed form) and this suite's own goals, with its rule, fixed before the run, and what this run "
               "measured (`trl_dgpq/analysis/claims.py` says how each kind is judged; a claim judged on a run that "
               "uses the env's model is a variant, counted apart); the sections below have the tables and "
               "figures.\n\n" + table(judged) + "\n\n") if judged else ""
    (out / "claims.md").write_text(table(judged) + "\n")   # the table alone: the docs site includes it
    write_summary(out, command, judged, summaries, shown)
    path = out / "REPORT.md"
    path.write_text(head + summary + "\n".join(sections) + "\n" + cost_section(loaded))
    from trl_dgpq.analysis import results
    results.write([results.row(name, run) for _, runs in loaded for name, run in runs.items()], out / "results.csv")
    return path


def write_summary(out: Path, command: str, judged: list, summaries: list, shown: list) -> None:
    """summary.md, what README.md shows: the tally, the domains in it and those not yet, and a
    paragraph and table per domain."""
    from trl_dgpq.analysis import published
    from trl_dgpq.analysis.claims import tally
    missing = [d.name for d, _ in reproductions() if d.name not in shown]
    where = "the published data" if published.is_published(out) else "the runs"
    words = lambda names: " and ".join(filter(None, [", ".join(names[:-1]), names[-1]])) if names else "none"  # noqa
    (out / "summary.md").write_text(
        f"The claims of {words(shown)}, each judged by its rule on {where} of `{command}` "
        f"([the report](results/report/REPORT.md)): {tally(judged)}."
        + (f" Not in this report yet: {words(missing)}." if missing else "") + "\n\n" + "\n".join(summaries))


def domain_summary(d, analysis, judged) -> str:
    """The README's paragraph on a domain: what it runs (its analysis' ``SUMMARY``, words only) and its
    claims' verdicts, one row each."""
    rows = ["| claim | ours | verdict |", "|---|---|---|"]
    cell = lambda text: text.replace("|", "\\|")  # noqa: E731
    rows += [f"| {j.claim.source}: {cell(j.claim.statement)}{' *(uses the model)*' if j.variant else ''} "
             f"| {cell(j.ours)} | {j.verdict} |" for j in judged]
    return (f"**{getattr(analysis, 'TITLE', d.name)}.** {getattr(analysis, 'SUMMARY', '')}\n\n"
            + ("\n".join(rows) + "\n" if judged else ""))


CLUSTERS = (2, 16, 64, 256)   # cores: this machine, and Ray clusters of 1, 4 and 16 16-core nodes


def cost_section(loaded) -> str:
    """What the runs cost: each experiment's wall time (its rows' ``wall_s``: a batch's time,
    shared among its seeds), the total on one core, and the plan's wall time on more cores."""
    from trl_dgpq.analysis import published
    jobs, rows, commits = [], [], set()
    for _, runs in loaded:
        for name, run in runs.items():
            # a sweep experiment's rows carry their job; a plain run folder is one job
            per_job = (run.df.groupby("job")["wall_s"].sum() if "job" in run.df else run.df[["wall_s"]].sum())
            jobs += list(per_job)
            commits.update(published.commits_of(run))
            rows.append(f"| {name} | {run.df.seed.nunique()} | {run.df.steps.sum():,} | {per_job.sum() / 60:,.1f} "
                        f"| {ms_per_seed_step(run.df):.2f} |")
    if not jobs:
        return ""
    total = sum(jobs)
    projected = ", ".join(f"{n} cores {sweep.makespan(jobs, n) / 3600:.2f} h" for n in CLUSTERS)
    return ("## What it cost\n\nEach experiment's wall time is the sum of its rows' `wall_s` (the time of the "
            "seed batch, shared among its seeds; process start-up not counted), measured on this machine while "
            "other work shared its cores, so a quiet machine is faster.\n\n"
            "| experiment | seeds | seed-steps | wall, min | ms per seed-step |\n|---|---|---|---|---|\n"
            + "\n".join(rows) + f"\n\nIn all {total / 3600:.2f} h of one core over {len(jobs)} jobs. The same jobs "
            f"scheduled longest first on more cores (`collectors/sweep.py` makespan; a Ray cluster of that many "
            f"cores, one job per core, start-up and transfers ignored; the longest job, "
            f"{max(jobs) / 3600:.2f} h, bounds it): {projected}. Runs made at commits "
            f"{', '.join(sorted(commits))}.\n")


def like(config: dict, measured: dict, rows_of) -> tuple:
    """(name, how) of the published experiment whose time per seed-episode stands for a planned one's:
    itself (the same settings), else the one of the same env and agent with the fewest env and agent
    settings different (then the most seed-episodes, ``rows_of(name)``: read only for those tied);
    (None, "") if none has its env and agent."""
    mine = same_config(config)
    same = [n for n, c in measured.items() if c["_same"] == mine]
    if same:
        return same[0], "measured"
    found = [n for n, c in measured.items() if all(c["run"].get(k) == config["run"].get(k) for k in ("env", "agent"))]
    if not found:
        return None, ""

    def differ(name: str) -> int:
        theirs = measured[name]["_same"]
        return sum(theirs[section].get(k) != v for section in ("env", "agent") for k, v in mine[section].items())
    fewest = min(map(differ, found))
    tied = [n for n in found if differ(n) == fewest]
    best = tied[0] if len(tied) == 1 else min(tied, key=lambda n: -len(rows_of(n)))   # a file read only for a tie
    return best, f"like {best}, {count(fewest, 'setting')} apart"


# What a job costs besides its steps at the published rate: fitted, not measured. A job's start
# (a worker forked, its env and agent built, its files written; not in the rows' wall_s) took 0.3-1.1 s
# for a one-episode job from a warm forkserver (load ~6, 2026-11-28). (Before 2026-11-29 a job's seeds
# were costed per seed at the published batch's rate, which a small batch runs 3.3x over at the median.)
# Replayed on two quick-scale runs (108 jobs at load ~7, 58 at ~3), the sweep's time-left guide was
# within 25 % (or 6 s) at 86 of 107 and 57 of 57 of its reports with 1 s; with 3 s, at 46 and 57 (it
# took the many small jobs at the end for longer ones). Measured quiet with 1 s: 90 of 107
# (docs/reproducing.md). All three before a running job kept a floor (sweep.running_left).
JOB_START_S = 1.0
PUBLICATION = Path(__file__).resolve().parents[2] / "results" / "report"   # the times --plan estimates from
# The time-left guide's rate (sweep.rate) counts the estimate as this many seconds of jobs run at it:
# the estimate is near the truth over a whole run (x0.96-1.09 measured on the quick scale) but a
# single job strays 0.6-2.5 times, so the rate of the first few jobs alone misled the guide (gym's DQN,
# started first, ran at ~0.6 of their estimates and set too fast a rate for the rest). Replayed on the
# quick scale's run of 2026-11-29 (bench.py quick --replay), the guide was within 25 % at 97 of 119
# reports with 0 s, 107 with 60, 114 with 120 and 119 with 240. Fitted on that one run: the next,
# run with it, was within 25 % at 119 of 119, but replayed it is so with any prior from 0 to 480 s
# (its first jobs ran near their estimates). Beside a full-scale run's hours of jobs it fades after
# the first few. On a host ~3x faster per step than the publication's (2026-11-29, 14:24,
# bench-quick-1129g: the sweep 1.8 minutes), 240 s outweighed every job run and the guide was
# within 25 % at 52 of 119 reports; replayed there, 92 with 0 s, 117 with 30, 114 with 60, 111 with
# 120. 120 s is the best worst case of the three runs (114, 119 and 111 of 119).
GUIDE_PRIOR_S = 120.0


def guide_prior(found: list) -> float:
    """``GUIDE_PRIOR_S`` where some experiment is estimated (``estimate``'s ``found``), else 0: with
    none, ``job_cost`` counts seed-steps, not seconds, and a prior in seconds would mean nothing."""
    return GUIDE_PRIOR_S if any(seconds is not None for _, seconds, _ in found) else 0.0


def estimate(planned: dict, publication: Path) -> list:
    """[(name, seconds or None, how)] of each planned experiment, one job each, from a published
    experiment like it (``like``): with an env-step budget, its seeds times the budget times that
    one's time per step; else its seeds times its episodes times that one's time per seed-episode
    over its first as many episodes (learning changes what an episode costs): CPU time where its
    rows record it, else wall time (published before, on 2 loaded cores); plus
    ``JOB_START_S``. Its seeds count as the published batch's where they are fewer (a small batch costs
    about as much per batched step): an estimate, not a promise."""
    from functools import cache

    from trl_dgpq.analysis import published
    measured = {}
    wanted = {(c["run"]["env"], c["run"]["agent"]) for c in planned.values()}
    if published.is_published(publication):
        for name in published.manifest(publication)["experiments"]:
            recorded = published.recorded_config(publication, name)
            if (recorded["run"]["env"], recorded["run"]["agent"]) in wanted:   # ``like`` takes no other
                sections = {k: recorded[k] for k in ("run", "env", "agent")}
                measured[name] = {**sections, "_same": same_config(sections)}

    @cache
    def rows_of(name: str):   # the rows of the experiments chosen (or tied), each read once
        df = published.load(publication, name, columns=("cpu_s", "wall_s")).df
        return df[["episode", "steps"]].assign(spent=spent_seconds(df))
    likes = {name: like(config, measured, rows_of) for name, config in planned.items()}
    # each chosen one's rows read once, on every core: decompressing and parsing release the GIL
    # (132 files for the quick plan: ~10 s in turn, ~6 s on 2 threads)
    with ThreadPoolExecutor(os.cpu_count() or 1) as pool:
        list(pool.map(rows_of, {source for source, _ in likes.values() if source is not None}))
    out = []
    for name, config in planned.items():
        source, how = likes[name]
        if source is None:
            out.append((name, None, "no published experiment like it"))
            continue
        rows, run = rows_of(source), config["run"]
        # a batch of fewer seeds than the published one costs as much per batched step (its cost is the
        # step's overhead more than its seeds': measured on the quick scale, 2026-11-29), more seeds per seed
        seeds = max(len(run["seeds"]), len(measured[source]["run"]["seeds"]))
        if run.get("env_steps"):       # a budget, or its episodes at the published run's steps per episode
            steps = min(run["env_steps"], run["episodes"] * float(rows["steps"].mean()))
            seconds = seeds * steps * float(rows["spent"].sum() / rows["steps"].sum())
        else:                          # its episodes at the time per seed-episode over as many episodes there
            ran = int(rows.episode.max())
            per = float(rows[rows.episode <= run["episodes"]]["spent"].mean())
            # a plan longer than the published run: its later episodes at the rate of its last 10 %
            tail = float(rows[rows.episode > 0.9 * ran]["spent"].mean())
            seconds = seeds * (per * min(run["episodes"], ran) + tail * max(0, run["episodes"] - ran))
        out.append((name, JOB_START_S + seconds, how))
    return out


def spent_seconds(df):
    """Each row's seconds of one core: its CPU time where recorded, else its wall time (which grows
    with whatever else shares the cores; rows from before ``cpu_s`` have only it)."""
    return df["cpu_s"].fillna(df["wall_s"]) if "cpu_s" in df else df["wall_s"]


def job_share(seconds: float, seeds: int, of: int) -> float:
    """A job's estimated seconds: its start and its ``seeds`` of ``of`` seeds' share of the
    experiment's estimated ``seconds`` of steps."""
    return JOB_START_S + (seconds - JOB_START_S) * seeds / of


def own_time_left(jobs: list) -> Dict[str, float]:
    """{job folder: its ``seconds_left``} of the jobs begun (or finished) in their folders."""
    return {j.folder: left for j in jobs if (left := readable_time_left(j)) is not None}


def readable_time_left(job) -> Optional[float]:
    """``seconds_left`` of ``job``'s folder; None (left to its estimate) where the folder cannot be
    read: a guide is no reason to stop a reproduction, nor its plan."""
    try:
        return seconds_left(job.folder, job.config["run"])
    except (ValueError, OSError, KeyError, TypeError, AttributeError):   # damaged rows, a missing column
        return None


def job_cost(planned: dict, found: list, own: Optional[Dict[str, float]] = None):
    """Job -> its estimated seconds (``estimate``'s ``found``, its share of its experiment's seeds), for
    the sweep's time-left guide; a job of an experiment with no estimate at its planned seed-steps times
    the median seconds per planned seed-step of those with one (all at their seed-steps if none has). A
    job begun before, in ``own`` ({job folder: its ``seconds_left``}), costs what it has left: counted
    whole, a job resumed near its end would make the rate of the jobs after it look fast."""
    own = own or {}
    estimated = {name: seconds for name, seconds, _ in found if seconds is not None}
    steps = sweep.planned_seed_steps
    rates = sorted((estimated[n] - JOB_START_S) / steps(sweep.Job(n, 0, planned[n]["run"]["seeds"], "", planned[n]))
                   for n in estimated)
    rate = rates[len(rates) // 2] if rates else 1.0

    def cost(job) -> float:
        if job.folder in own:
            return own[job.folder]
        seconds = estimated.get(job.experiment)
        if seconds is not None:
            return job_share(seconds, len(job.seeds), len(planned[job.experiment]["run"]["seeds"]))
        return JOB_START_S + steps(job) * rate
    return cost


def seed_groups(planned: dict, found: list, max_minutes: Optional[float]) -> Dict[str, int]:
    """{experiment: jobs} for the experiments whose estimate (``estimate``'s ``found``) is over
    ``max_minutes`` of one core: the fewest groups of consecutive seeds whose estimated share is
    within it (at most one seed each). None: every experiment one job."""
    if max_minutes is None:
        return {}
    limit = max_minutes * 60 - JOB_START_S   # of steps, a job's start apart (none left: a seed a job)
    out = {}
    for name, seconds, _ in found:
        if seconds is not None and seconds - JOB_START_S > limit:
            seeds = len(planned[name]["run"]["seeds"])
            out[name] = min(seeds, math.ceil((seconds - JOB_START_S) / limit)) if limit > 0 else seeds
    return out


def job_seconds(planned: dict, found: list, groups: Dict[str, int]) -> List[float]:
    """The estimated seconds of every job of the experiments with an estimate: an experiment's
    steps shared by its jobs' seeds (``sweep.plan``'s groups), each job its own start."""
    out = []
    for name, seconds, _ in found:
        if seconds is None:
            continue
        config = planned[name]
        n = len(config["run"]["seeds"])
        out += [job_share(seconds, len(job.seeds), n) for job in sweep.plan({name: config}, "", None, groups)]
    return out


def seconds_left(folder: str, run: dict) -> Optional[float]:
    """A begun job's time left by its own episodes, in seconds of one core: 0 if finished; None if no
    checkpoint covers an episode yet. Only the rows its checkpoint covers count (a resume runs those
    after it again: after a hard kill, up to ``checkpoint_every`` episodes). Its batch CPU time per episode (every seed's ``cpu_s``: the wall time rises with
    whatever else shares the cores, the CPU time does not; ``wall_s`` for rows without it), fitted by a
    line over the second half of the episodes all its seeds ran, summed over the episodes left: an
    F-16 DGPQ job without a potential pays more each episode as its Q̂ grows, which a mean would miss.
    A job with an env-step budget: its steps left at its time per step over that second half."""
    import numpy as np
    import pandas as pd
    folder = runner.RunFolder(folder)
    if folder.finished():
        return 0.0
    try:
        df = pd.read_csv(folder.path / runner.EPISODES, usecols=lambda c: c in ("seed", "episode", "steps", "wall_s",
                                                                                "cpu_s"))
    except (FileNotFoundError, pd.errors.EmptyDataError):
        return None
    covered = folder.checkpointed(run["seeds"])
    if covered is None:
        return None
    df = df[df["episode"] <= df["seed"].map(covered)].copy()
    df["spent"] = spent_seconds(df)
    per = df.groupby("episode").agg(seeds=("seed", "nunique"), steps=("steps", "max"), spent=("spent", "sum"))
    per = per[per.seeds == len(run["seeds"])]
    if per.empty:
        return None
    done = int(per.index.max())
    late = per[per.index > done // 2]
    if run.get("env_steps"):   # the seed furthest from its budget sets how long the batch goes on
        steps_left = max(0.0, run["env_steps"] - float(df.groupby("seed")["steps"].sum().min()))
        return JOB_START_S + steps_left * float(late.spent.sum() / late.steps.sum())
    e, t = late.index.to_numpy(float), late.spent.to_numpy(float)
    slope = max(0.0, float(np.polyfit(e, t, 1)[0])) if len(e) >= 4 else 0.0
    level = float(t.mean() - slope * e.mean())         # the line through the mean at that slope
    first, last = done + 1, run["episodes"]
    if last < first:
        return JOB_START_S
    n = last - first + 1
    return JOB_START_S + max(0.0, n * level + slope * (last * (last + 1) - done * (done + 1)) / 2)


def begun(out: Path, planned: dict) -> Dict[str, list]:
    """{experiment: [(seeds, seconds left) of each of its jobs (``seconds_left``)]} of the planned
    experiments a reproduction in ``out`` has begun (its sweep's jobs); {} if none is there."""
    if not (out / sweep.SWEEP).is_file():
        return {}
    _, jobs = sweep.load(out)
    got: Dict[str, list] = {}
    for job in jobs:
        if job.experiment in planned:
            got.setdefault(job.experiment, []).append((len(job.seeds), readable_time_left(job)))
    return {name: left for name, left in got.items() if any(s is not None for _, s in left)}


def hours(seconds: float) -> str:
    return f"{seconds / 3600:,.2f} h" if seconds >= 3600 else f"{seconds / 60:.1f} min"


def plan_text(planned: dict, publication: Path, max_minutes: Optional[float] = None, out: Optional[Path] = None) -> str:
    """What ``--plan`` prints: each part's experiments with their estimated time (and jobs, where
    ``max_minutes`` splits them), the total on one core and the makespan on more. With ``out``, a
    reproduction under way there: an experiment it has begun counts its time left by its own
    episodes (``begun``) in place of the estimate, a job not yet started at its share of it."""
    found = estimate(planned, publication)
    groups = seed_groups(planned, found, max_minutes)
    own = begun(out, planned) if out is not None else {}
    lines, jobs, unknown_jobs = [], [], 0
    for name, seconds, how in found:
        config = planned[name]["run"]
        size = f"{count(len(config['seeds']), 'seed')} x {config['episodes']:,}"
        if name in own:   # a job not started yet: its share of the estimate (none: not estimated)
            left = [s if s is not None else job_share(seconds, n, len(config["seeds"])) if seconds is not None else None
                    for n, s in own[name]]
            estimated = [s for s in left if s]
            jobs += estimated
            unstarted = sum(s is None for s in left)
            unknown_jobs += unstarted
            if estimated:
                state = f"~{sum(estimated) / 60:,.1f} min left (begun in {out}: by its own episodes' CPU time)"
            else:
                state = "begun" if unstarted else f"finished in {out}"
            lines.append(f"  {name}: {size}, {state}"
                         + (f", {count(unstarted, 'job')} not started and not estimated" if unstarted else ""))
            continue
        split = f" in {groups[name]} jobs" if name in groups else ""
        lines.append(f"  {name}: {size}, " + (f"~{seconds / 60:,.1f} min{split} ({how})" if seconds is not None else how))
        jobs += job_seconds(planned, [(name, seconds, how)], groups)
    unknown = sum(s is None and name not in own for name, s, _ in found) + unknown_jobs
    total = sum(jobs)
    cores = ", ".join(f"{n} cores ~{hours(sweep.makespan(jobs, n))}" for n in CLUSTERS) if jobs else "-"
    how = (f"{len(jobs) + unknown} jobs (those over {max_minutes:g} min of one core split into seed groups)"
           if max_minutes is not None else "one job each")
    under_way = (f" left, {len(own)} of them begun in {out} (those by their own episodes' CPU time, the others by "
                 "published wall time)" if own else "")
    return ("\n".join(lines) + f"\n{len(found)} experiments, {how}: ~{hours(total)} of one core{under_way}"
            + (f" and wall time {cores}, both without the {unknown} not estimated" if unknown else f"; wall time {cores}")
            + " (longest job first; "
            f"times per seed-episode from {publication}, CPU time where recorded, else wall time on 2 loaded cores)\n")


def parts_of(manifest: dict) -> list:
    """A publication's parts: its ``only``, or every part where that is empty."""
    return manifest["only"] or [part.name for part, _ in reproductions()]


def kept_parts(earlier: dict, scale: str, only) -> list:
    """The parts of an earlier publication (its manifest) that publishing ``only`` into its folder
    keeps as they are: those it holds that ``only`` does not name; none where ``only`` is every part.
    Refused at another scale: the parts of one publication share its scale."""
    if earlier is None or not only:
        return []
    keep = [p for p in parts_of(earlier) if p not in only]
    if keep and earlier["scale"] != scale:
        raise ValueError(f"the folder holds the {earlier['scale']} scale's publication of {', '.join(keep)}: "
                         f"publishing {', '.join(only)} at the {scale} scale into it would lose them; publish "
                         "into another folder, or every part")
    return keep


def kept_experiments(to: Path, earlier: dict, scale: str, keep: list) -> list:
    """The experiments of the ``keep`` parts the earlier publication in ``to`` holds, each refused
    where today's plan differs from the settings it ran with (its rows would not be the plan's)."""
    from trl_dgpq.analysis import published
    planned = experiments(scale, keep)
    names = [n for n in earlier["experiments"] if n in planned]
    moved = [n for n in names if same_sections(published.recorded_config(to, n)) != same_sections(planned[n])]
    if moved:
        raise ValueError(f"the plan of {', '.join(moved)} changed since they were published: run them again "
                         "(their parts' --only) and publish those parts too")
    return names


def publish(out: Path, to: Path, scale: str, only=None) -> list:
    """What the repository keeps of the reproduction in ``out`` (e.g. into results/report): the
    per-episode data and configs of its finished experiments (``analysis/published.py``), the data
    of the figures drawn from checkpoints, and REPORT.md, claims.md, results.csv, summary.md,
    sections/ and the figures rebuilt from those alone. Built beside ``to`` and then put in its
    place whole, so a failure leaves the earlier publication as it was; ``to`` must be an earlier
    publication, empty, or absent (it holds the publication alone), and apart from ``out``.
    Publishing some parts (``only``) into an earlier publication of the same scale replaces those
    parts and keeps its others as they were published (data copied byte for byte, the manifest
    naming where they came from: ``kept``), so adding a part never needs the runs of the rest."""
    import shutil

    from trl_dgpq.analysis import published
    from trl_dgpq.selection import check_reportable
    out, to = Path(out).resolve(), Path(to).resolve()
    if out == to or out in to.parents or to in out.parents:
        raise ValueError(f"publish into a folder apart from the runs' ({to} and {out} hold one another)")
    if to.exists() and (not to.is_dir() or (any(to.iterdir()) and not published.is_published(to))):
        raise ValueError(f"{to} is neither an earlier publication nor empty: publish into a folder of its own")
    earlier = published.manifest(to) if published.is_published(to) else None
    keep = kept_parts(earlier, scale, only)
    kept = kept_experiments(to, earlier, scale, keep) if keep else []
    planned = experiments(scale, only)
    names = [name for name in planned if finished(out, name)]
    if not names:
        raise ValueError(f"{out} holds no finished experiment to publish")
    for name in names:     # seeds that chose anything are never published (selection.py): the plan's, the runs'
        check_reportable(planned[name], name, publication=True)
        check_reportable(load_run(out / name).config, name, publication=True)
    if keep:               # the publication's parts in their earlier order, those new to it after
        theirs = parts_of(earlier)
        only = theirs + [p for p in only if p not in theirs]
    # the code that publishes, as committed (runner.provenance: its files unchanged)
    stamp = {**published.stamp(scale, only, f"python scripts/reproduce.py --scale {scale}"
                                              + (" --only " + " ".join(only) if only else "")),
             "planned": list(experiments(scale, only) if keep else planned)}
    if keep:
        stamp["kept"] = published.kept_record(earlier, keep, kept)
    new, old = to.with_name(f".{to.name}.new"), to.with_name(f".{to.name}.old")
    for leftover in (new, old):
        shutil.rmtree(leftover, ignore_errors=True)
    try:
        published.write_data(out, new, names, stamp, kept_from=to if kept else None, kept=kept)
        for figure in published.CHECKPOINT_FIGURES:
            # a kept part's figure as it was published; a part published now, its runs'; no other part's
            part = Path(figure).parts[0]
            source = to if part in keep else out
            if (not only or part in only) and (source / figure).is_file():
                (new / figure).parent.mkdir(parents=True, exist_ok=True)
                shutil.copy2(source / figure, new / figure)
        write_report(new, scale, 0.0, only)
    except BaseException:
        shutil.rmtree(new, ignore_errors=True)
        raise
    if to.exists():
        os.replace(to, old)
    os.replace(new, to)
    shutil.rmtree(old, ignore_errors=True)
    return sorted(p for p in to.rglob("*") if p.is_file())


def chosen(planned: dict, patterns) -> list:
    """The planned experiments that ``patterns`` (names or shell patterns; None: all) match, in plan
    order; a pattern that matches none is refused, with the names it could have meant."""
    if patterns is None:
        return list(planned)
    unmatched = [p for p in patterns if not any(fnmatch.fnmatchcase(n, p) for n in planned)]
    if unmatched:
        raise sweep.SweepError(f"--experiments {' '.join(unmatched)}: no planned experiment matches; planned: "
                               + ", ".join(planned))
    return [n for n in planned if any(fnmatch.fnmatchcase(n, p) for p in patterns)]


def rebuild(folder: Path) -> Path:
    """REPORT.md and the rest, again, from the published data in ``folder`` alone."""
    from trl_dgpq.analysis import published
    stamp = published.manifest(folder)
    return write_report(folder, stamp["scale"], 0.0, stamp["only"] or None)


def positive_minutes(text: str) -> float:
    value = float(text)
    if not (value > 0 and math.isfinite(value)):
        raise argparse.ArgumentTypeError(f"must be a number of minutes > 0, got {text!r}")
    return value


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog=prog("reproduce"), description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--scale", choices=SCALES, default="quick")
    p.add_argument("--out", default=None, help="folder (default: runs/reproduce-SCALE); an existing one continues")
    p.add_argument("--workers", type=int, default=os.cpu_count())
    p.add_argument("--only", nargs="+", choices=[d.name for d, _ in reproductions()], default=None, metavar="PART",
                   help="these parts' experiments and sections only (a domain, or an experiment apart; default: all): "
                        + ", ".join(d.name for d, _ in reproductions()))
    p.add_argument("--reuse", nargs="+", default=[], metavar="DIR",
                   help="other sweep folders (e.g. runs/compare): an experiment not begun here that finished "
                        "there with the same settings is copied in, not run again")
    p.add_argument("--experiments", nargs="+", default=None, metavar="PATTERN",
                   help="run only the planned experiments these names or shell patterns match (e.g. 'liq-dgpq-*'); "
                        "the plan stays whole, and a later call without it runs the rest")
    p.add_argument("--max-job-minutes", type=positive_minutes, default=None, metavar="M",
                   help="split each experiment whose estimate (as --plan's) is over M minutes of one core into "
                        "the fewest jobs of consecutive seeds within it, which the workers (or a Ray cluster) run "
                        "apart: the same rows, a shorter wall time on many cores (default: one job each; a "
                        "reproduction under way keeps the jobs it began with)")
    p.add_argument("--plan", action="store_true",
                   help="run nothing: list the planned experiments with their estimated time (from the published "
                        "runs like each; one begun in --out, by its own episodes' times) and the wall time on 2, 16, "
                        "64 and 256 cores")
    p.add_argument("--sweep-file", default=None, metavar="FILE",
                   help="run nothing: write the planned experiments (those --experiments picks, if given) as a sweep "
                        "file for `trl-dgpq sweep`, the same configs")
    p.add_argument("--report", action="store_true",
                   help="run nothing: write REPORT.md, claims.md and results.csv from what has finished so far "
                        "(a domain's section once all its experiments have)")
    p.add_argument("--publish", default=None, metavar="DIR",
                   help="when done, keep the finished experiments' per-episode data and configs in DIR/data and "
                        "rebuild REPORT.md, claims.md, results.csv, summary.md and the figures in DIR from them "
                        "alone (what results/ keeps; `trl-dgpq report DIR` rebuilds them again); with --only, into "
                        "an earlier publication, the parts it names replace theirs and the others are kept")
    args = p.parse_args(argv)
    suffix = "".join(f"-{d}" for d in args.only or ())
    out = Path(args.out or f"runs/reproduce-{args.scale}{suffix}")
    planned = experiments(args.scale, args.only)

    def body() -> int:
        now = chosen(planned, args.experiments)
        if args.experiments and args.report:
            raise sweep.SweepError("--report writes the report of every finished experiment: drop --experiments")
        if args.sweep_file:
            given = plan_settings(args.scale, args.only)
            command = " ".join([prog("reproduce"), "--scale", args.scale]
                               + (["--only", *args.only] if args.only else [])
                               + (["--experiments", *args.experiments] if args.experiments else [])
                               + ["--sweep-file", args.sweep_file])
            Path(args.sweep_file).write_text(sweep_file({n: given[n] for n in now}, command))
            print(f"wrote {args.sweep_file}: {count(len(now), 'experiment')}")
            return 0
        if args.plan:
            print(plan_text({n: planned[n] for n in now}, PUBLICATION, args.max_job_minutes, out), end="")
            return 0
        if args.report:
            if not (out / sweep.SWEEP).is_file():
                raise sweep.SweepError(f"{out} holds no reproduction to report on")
            path = write_report(out, args.scale, 0.0, args.only)
            print(f"wrote {path} ({sum(finished(out, n) for n in planned)} of {len(planned)} experiments finished)")
            if args.publish:
                print(f"published {len(publish(out, Path(args.publish), args.scale, args.only))} files to "
                      f"{args.publish}")
            return 0
        # the workers' imports begin on another core while the plan reads the published data
        sweep.start_forkserver(sweep.job_modules(planned[n] for n in now))
        found = estimate(planned, PUBLICATION)   # read once (seconds of published data): the split and the guide
        groups = seed_groups(planned, found, args.max_job_minutes)
        if (out / sweep.SWEEP).is_file():
            # experiments added to the plan since (a new agent, a new domain) join the finished ones
            jobs = sweep.grow(out, planned, None, same=lambda a, b: same_run(a) == same_run(b), groups=groups)
            print(f"continuing {out}", flush=True)
        else:
            jobs = sweep.plan(planned, out, None, groups)
            sweep.create(out, planned, jobs)
        if args.reuse:
            jobs = sweep.reuse(out, jobs, args.reuse, same=lambda a, b: same_config(a) == same_config(b),
                               log=lambda line: print(line, flush=True))
        cost = job_cost(planned, found, own_time_left(jobs))
        jobs = in_order([j for j in jobs if j.experiment in now], args.workers, cost)
        print(f"reproduce ({args.scale}) -> {out}: {len(planned)} experiments"
              + (f", {len(now)} of them now" if len(now) < len(planned) else "") + f", {args.workers} workers",
              flush=True)
        t0 = time.perf_counter()
        report = sweep.execute(out, jobs, "local", args.workers, log=lambda line: print(line, flush=True),
                               cost=cost, prior=guide_prior(found))
        if sweep.exit_code(report, "the same command"):
            return 1
        path = write_report(out, args.scale, time.perf_counter() - t0, args.only)
        print(f"wrote {path}, {out / 'results.csv'} and the figures", flush=True)
        if args.publish:
            copied = publish(out, Path(args.publish), args.scale, args.only)
            print(f"published {len(copied)} files to {args.publish}", flush=True)
        return 0
    return sweep.run_script(prog("reproduce"), "the same command", body)


if __name__ == "__main__":
    sys.exit(main())
